"""Fast DDS shared-memory health-check sleeps around the start of the realtime loop, with and without the settle.

Linux only. Runs the three nodes in realtime on paper-circle, `--runs` times
per arm, the arms interleaved: the trajectory's ``start_settle_s`` at 0 (the
loop starts as soon as the controller has an odometry and a preview) and at
`--settle`. Beside each run a sampler reads every thread of the three
processes every 5 ms (``/proc/PID/task/*/syscall``); a thread seen in
nanosleep or clock_nanosleep for 200 ms or more is counted as a sleep (the
health check of bench/README.md sleeps 333 ms), timed from the plant's first
answered tick. Prints one line per run and a summary per arm.

    python -m robotino_geom_mpc.bench.startup_stalls [--runs 20] [--duration 6] [--settle 1.0]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import threading
import time

from robotino_geom_mpc.bench.dds import lockstep_nodes, read_timing_report
from robotino_geom_mpc.bench.registry import BenchmarkError, wait_for_run
from robotino_geom_mpc.system.processes import TIMING_REPORT, NodeGroup

SLEEP_SYSCALLS = {"x86_64": {"35", "230"}, "aarch64": {"101", "115"}}  # nanosleep, clock_nanosleep
MIN_SLEEP_S = 0.2
SAMPLE_S = 0.005


def _read(path: str) -> str:
    try:
        with open(path) as f:
            return f.read()
    except OSError:
        return ""


class SleepSampler:
    """Threads of the given processes seen in a sleep syscall for `MIN_SLEEP_S` or more: (node, thread, start, s)."""

    def __init__(self, pids: dict[str, int], syscalls: set[str]) -> None:
        self.pids, self.syscalls = pids, syscalls
        self.sleeps: list[tuple[str, str, float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        since: dict[tuple[str, str], float] = {}
        while not self._stop.wait(SAMPLE_S):
            now = time.monotonic()
            for name, pid in self.pids.items():
                try:
                    tids = os.listdir(f"/proc/{pid}/task")
                except OSError:
                    continue
                for tid in tids:
                    key = (name, tid)
                    if _read(f"/proc/{pid}/task/{tid}/syscall").split(" ", 1)[0] in self.syscalls:
                        since.setdefault(key, now)
                    elif key in since:
                        start = since.pop(key)
                        if now - start >= MIN_SLEEP_S:
                            comm = _read(f"/proc/{pid}/task/{tid}/comm").strip()
                            self.sleeps.append((name, comm, start, now - start))

    def stop(self) -> list[tuple[str, str, float, float]]:
        self._stop.set()
        self._thread.join()
        return self.sleeps


def run_once(settle_s: float, duration_s: float, syscalls: set[str]) -> dict:
    """One realtime run; its missed ticks and sleeps (start relative to the first answer [s], length [s]).

    Raises `BenchmarkError` if a node fails, the run does not end, or the plant's timing report is missing
    or names no first answer.
    """
    with NodeGroup() as group:
        path = group.logs / TIMING_REPORT
        plant = lockstep_nodes(group, "paper-circle", duration_s, realtime=True,
                               trajectory_overrides={"start_settle_s": settle_s}, timing_report=path)
        sampler = SleepSampler({node.name: node.popen.pid for node in group.nodes}, syscalls)
        try:
            wait_for_run(group, plant, duration_s + 60.0, f"realtime run of {duration_s} s")
        finally:
            sleeps = sampler.stop()
        report = read_timing_report(path, "realtime")
    if report["first_answer_steady_s"] is None:
        raise BenchmarkError(f"the realtime run of {duration_s} s had no answered tick")
    t0 = report["first_answer_steady_s"]
    return {"missed": report["missed"], "gaps": [(after, gap) for after, gap in report["missed_ticks"]],
            "sleeps": [(f"{node}/{comm}", start - t0, length) for node, comm, start, length in sleeps]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20, help="runs per arm")
    parser.add_argument("--duration", type=float, default=6.0, help="plant duration_s of each run [s]")
    parser.add_argument("--settle", type=float, default=1.0, help="start_settle_s of the second arm [s]")
    args = parser.parse_args()
    syscalls = SLEEP_SYSCALLS.get(platform.machine())
    if not sys.platform.startswith("linux") or syscalls is None:
        print(f"needs Linux on {' or '.join(SLEEP_SYSCALLS)} (/proc syscall numbers)", file=sys.stderr)
        return 2
    arms = (0.0, args.settle)
    totals = {arm: {"runs": 0, "runs_with_misses": 0, "sleeps_before": 0, "sleeps_after": 0} for arm in arms}
    for i in range(args.runs):
        for arm in arms:
            try:
                run = run_once(arm, args.duration, syscalls)
            except BenchmarkError as exc:
                print(f"run {i} start_settle_s {arm:g}: {exc}", file=sys.stderr)
                return 1
            total = totals[arm]
            total["runs"] += 1
            total["runs_with_misses"] += run["missed"] > 0
            for _, start, _ in run["sleeps"]:
                total["sleeps_after" if start > 0 else "sleeps_before"] += 1
            line = f"run {i} start_settle_s {arm:g}: {run['missed']} missed"
            line += "".join(f"; {who} slept {1e3 * length:.0f} ms at {start:+.3f} s"
                            for who, start, length in run["sleeps"])
            line += "".join(f"; miss at {t:+.3f} s, {1e3 * gap:.1f} ms to the next odometry"
                            for t, gap in run["gaps"][:5])
            print(line, flush=True)
    for arm, total in totals.items():
        print(f"start_settle_s {arm:g}: {total}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
