"""Benchmark ``soak``: the realtime loop with the recorder over a long run, the controller killed and restarted, `run`
again and again.

Three parts, each on the current ROS_DOMAIN_ID:

* `soak`: the nodes of ``robotino-geom-mpc run --realtime`` (paper-circle, recorded) for `SOAK_S` (``--duration``),
  reported per window (`window_length`: 5 minutes, shorter for short runs): each process's resident memory (the
  mean of samples every `SAMPLE_S` from ``/proc``; all, anonymous and shared) and CPU, and the plant's missed
  ticks and odometry-to-command latency p50, p99, p99.9 in that window (its timing report's ``windows``,
  `loop_timing`); the bag's messages of the plant's topics against the ticks it published (the MCAP summary's
  counts). Memory growth is judged after the first (warm-up) window by a least-squares slope over the windows
  (`growth_mb_per_10min`, against `GROWTH_BOUND_MB_PER_10MIN`); latency drift by the last window against the
  first, over the steps between successive windows, with a permutation test of the windows' order
  (`latency_drift`).
* `restart_loop` (`bench.restarts`): the realtime loop with the controller killed by SIGKILL and started again
  `RESTARTS` times; Fast DDS's shared-memory segments and port files, the domain's UDP ports and the survivors'
  and the supervisor's descriptors before, after every restart (a slope per restart) and after the last.
* `run_loop`: ``robotino-geom-mpc run`` (lockstep, recorded, `RUN_S`) `RUNS` times in a row; every one must end
  with status 0 and its metrics.

Progress and the per-window table go to the log (stderr); the figures, flat, to the registry. The benchmark is
not part of a plain ``bench`` (it runs for most of an hour): ``bench --only soak [--duration S]``.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from robotino_geom_mpc.bench.registry import BenchmarkError, BenchmarkSkipped, benchmark

__all__ = ["DRIFT_ALPHA", "GROWTH_BOUND_MB_PER_10MIN", "PLANT_TOPICS", "SEQUENCED_TOPICS", "RESTARTS", "RUNS", "RUN_S",
           "SAMPLE_S", "SOAK_S", "WINDOW_S", "ProcessSampler", "bag_counts", "bag_sequences", "bench_soak",
           "growth_mb_per_10min", "latency_drift", "process_memory_cpu", "run_loop", "soak", "soak_table",
           "window_length"]

SOAK_S = 1800.0  # the soak's default length (quick: 60 s)
WINDOW_S = 300.0  # its windows (`window_length`: at most a sixth of the run)
SAMPLE_S = 2.0  # how often each process's memory and CPU are read
RESTARTS = 200  # controller kills and restarts (quick: 5)
RUNS = 100  # `run`s in a row (quick: 5)
RUN_S = 2.0  # each one's length
# messages a published tick of the plant's topics in the bag (realtime): its odometry, ground truth and wheels'
# joint states one each; /tf two: its odom -> base_link (publish_tf, the default) and the description publisher's
# wheel transforms (one per joint_states)
PLANT_TOPICS = {"/odom": 1, "/ground_truth/odom": 1, "/joint_states": 1, "/tf": 2}
# the plant's topics with one writer: their messages' DDS publication sequence numbers (the bag keeps them) run
# 1, 2, ... over the ticks, so a gap is a lost message and the first one tells what went before the recording
SEQUENCED_TOPICS = ("/odom", "/ground_truth/odom", "/joint_states")
# of these, published every tick whoever listens (its sequence number counts the ticks); the plant builds the
# others only while a subscription is matched, so their numbers start at the recorder's match, not at tick 1
EVERY_TICK_TOPICS = ("/odom",)
GROWTH_BOUND_MB_PER_10MIN = 1.0  # issue 27: no node's resident memory grows more after warm-up
DRIFT_ALPHA = 0.01  # a latency quantile drifted when `latency_drift`'s p-value is below this
_END_MARGIN_S = 120.0  # the soak's plant must have ended this long after its duration
# the stop's grace periods, `cli.run`'s: 5 s a node, the recorder 70 s (its drain limit and the bag's close)
_GRACE_S, _RECORDER_GRACE_S = 5.0, 70.0


def window_length(duration_s: float) -> float:
    """The soak's window: `WINDOW_S`, or a sixth of `duration_s` for runs shorter than six windows."""
    return min(WINDOW_S, duration_s / 6.0)


def process_memory_cpu(pid: int) -> tuple[float, float, float, float]:
    """Resident memory [bytes] of process `pid`: all (VmRSS), anonymous (RssAnon: its heaps) and shared
    (RssShmem: the pages it touched of shared-memory segments, Fast DDS's own and its peers'), and its user +
    system CPU time [s]; OSError once it is gone.
    """
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        kb = {key: int(rest.split()[0]) for key, _, rest in (line.partition(":") for line in f)
              if key in ("VmRSS", "RssAnon", "RssShmem")}
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (1024.0 * kb["VmRSS"], 1024.0 * kb["RssAnon"], 1024.0 * kb["RssShmem"],
            (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"))


class ProcessSampler:
    """Samples the memory and CPU time of named processes every `interval_s` in a thread (a context manager).

    `samples[name]` is a list of (steady time [s], RSS, anonymous, shared [bytes], CPU time [s],
    `process_memory_cpu`); `load` of (steady time [s], the
    machine's 1-minute load average).
    """

    def __init__(self, pids: dict[str, int], interval_s: float = SAMPLE_S) -> None:
        self.pids, self.interval_s = dict(pids), interval_s
        self.samples: dict[str, list[tuple[float, ...]]] = {name: [] for name in pids}
        self.load: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="soak-sampler", daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(self.interval_s)

    def sample(self) -> None:
        """One sample of every process still running, and of the machine's load."""
        self.load.append((time.monotonic(), os.getloadavg()[0]))
        for name, pid in self.pids.items():
            try:
                figures = process_memory_cpu(pid)
            except (OSError, KeyError, IndexError, ValueError):
                continue
            self.samples[name].append((time.monotonic(), *figures))

    def window(self, name: str, start: float, end: float) -> dict[str, float] | None:
        """`name`'s mean ``rss_mb``, ``anon_mb``, ``shmem_mb`` and its ``cpu_pct`` (% of one core) between
        steady times `start` and `end` (None: fewer than 2 samples).
        """
        inside = [s for s in self.samples[name] if start <= s[0] <= end]
        if len(inside) < 2:
            return None
        out = {key: statistics.fmean(s[k] for s in inside) / 1e6
               for k, key in enumerate(("rss_mb", "anon_mb", "shmem_mb"), start=1)}
        out["cpu_pct"] = 100.0 * (inside[-1][4] - inside[0][4]) / (inside[-1][0] - inside[0][0])
        return out

    def window_load(self, start: float, end: float) -> float:
        """The mean 1-minute load average of the machine between steady times `start` and `end` (NaN: none)."""
        inside = [value for t, value in self.load if start <= t <= end]
        return statistics.fmean(inside) if inside else float("nan")

    def __enter__(self) -> ProcessSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def growth_mb_per_10min(times_s: list[float], values_mb: list[float]) -> float:
    """The least-squares slope of `values_mb` over `times_s`, in MB per 10 minutes (NaN with fewer than 2)."""
    if len(times_s) < 2:
        return float("nan")
    return 600.0 * statistics.linear_regression(times_s, values_mb).slope


def latency_drift(values: list[float], alpha: float = DRIFT_ALPHA) -> dict[str, Any]:
    """Whether a latency quantile drifted between the first and the last window, beyond the windows' noise.

    The statistic is ``ratio`` = |last - first| over the root mean square of the steps between successive
    windows (the noise a window's figure has; unlike the spread around the mean, a trend does not inflate it:
    a steady trend of d per window makes the change (n - 1) d and every step d, the ratio its maximum n - 1).
    Its p-value is exact for windows that are exchangeable (no drift): the fraction of the orderings of the
    windows (all of them up to 8 windows, else 20000 drawn, seeded) whose ratio is at least the observed one.
    A window's sample of some 10^4 latencies makes a two-sample test of the first and last window (Mann-Whitney,
    Kolmogorov-Smirnov) find any difference of load between them significant; this one asks whether the change
    stands out from how much the windows move anyway.

    Returns ``first``, ``last``, ``change`` (last - first), ``step`` (RMS of successive differences), ``ratio``,
    ``p`` and ``drift`` (p < `alpha`); NaN and no verdict (``drift`` None) with fewer than 3 windows.
    """
    import itertools

    import numpy as np

    v = np.asarray(values, dtype=float)
    out: dict[str, Any] = {"first": float("nan"), "last": float("nan"), "change": float("nan"),
                           "step": float("nan"), "ratio": float("nan"), "p": float("nan"), "drift": None}
    if len(v) < 3:
        return out

    def ratios(orders: np.ndarray) -> np.ndarray:
        steps = np.sqrt(np.mean(np.diff(orders, axis=1) ** 2, axis=1))
        change = np.abs(orders[:, -1] - orders[:, 0])
        return np.divide(change, steps, out=np.zeros_like(change), where=steps > 0)

    if len(v) <= 8:
        orders = v[np.array(list(itertools.permutations(range(len(v)))))]
    else:
        rng = np.random.default_rng(0)
        orders = np.array([v[rng.permutation(len(v))] for _ in range(20000)])
    observed = float(ratios(v[None, :])[0])
    p = float(np.mean(ratios(orders) >= observed * (1.0 - 1e-12)))
    step = float(np.sqrt(np.mean(np.diff(v) ** 2)))
    out.update(first=float(v[0]), last=float(v[-1]), change=float(v[-1] - v[0]), step=step, ratio=observed, p=p,
               drift=p < alpha)
    return out


def bag_counts(bag: str | os.PathLike) -> dict[str, int]:
    """Messages per topic of a closed bag, from its MCAP files' summary statistics (not a message read)."""
    from mcap.reader import make_reader

    counts: dict[str, int] = {}
    for file in sorted(Path(bag).glob("*.mcap")):
        with open(file, "rb") as f:
            summary = make_reader(f).get_summary()
        if summary is None or summary.statistics is None:
            raise BenchmarkError(f"{file} has no summary statistics (not closed?)")
        for channel_id, count in summary.statistics.channel_message_counts.items():
            topic = summary.channels[channel_id].topic
            counts[topic] = counts.get(topic, 0) + count
    return counts


def bag_sequences(bag: str | os.PathLike, topics: tuple[str, ...]) -> dict[str, tuple[int, int, int]]:
    """Per topic of `topics` (each with one writer): (messages, first and last publication sequence number)."""
    from mcap.reader import make_reader

    seen: dict[str, list[int]] = {}
    for file in sorted(Path(bag).glob("*.mcap")):
        with open(file, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(topics=list(topics)):
                entry = seen.setdefault(channel.topic, [0, message.sequence, message.sequence])
                entry[0] += 1
                entry[1], entry[2] = min(entry[1], message.sequence), max(entry[2], message.sequence)
    return {topic: (count, first, last) for topic, (count, first, last) in seen.items()}


def _stop_like_run(group, nodes: dict) -> None:
    """Stop the nodes as `run` does: the loop's nodes first (SIGINT, escalating), then the recorder (its drain)."""
    import signal

    others = [name for name in nodes if name not in ("plant_node", "recorder_node")]
    for name in others:
        nodes[name].popen.send_signal(signal.SIGINT)
    statuses = {name: group.stop_node(nodes[name], _GRACE_S) for name in [*others, "plant_node"]}
    nodes["recorder_node"].popen.send_signal(signal.SIGINT)
    statuses["recorder_node"] = group.stop_node(nodes["recorder_node"], _RECORDER_GRACE_S)
    bad = {name: code for name, code in statuses.items() if code not in (0, -signal.SIGINT)}
    if bad:
        raise BenchmarkError(f"soak: nodes did not stop cleanly: {bad}:\n" + "\n".join(
            nodes[name].stderr_tail() for name in bad))


def soak(duration_s: float, folder: Path, log: Callable[[str], None]) -> dict[str, Any]:
    """Run the realtime loop with the recorder for `duration_s` into `folder`; the per-window table and the summary.

    Returns ``windows`` (per window: start and end [s from the first], ticks, missed, latency_ms, and per process
    ``rss_mb`` and ``cpu_pct``), ``ticks``, ``bag`` (topic -> count), ``short`` (topic of `PLANT_TOPICS` -> ticks
    less its count), ``lost`` (topic of `SEQUENCED_TOPICS` -> sequence numbers missing between its first and last
    recorded message), ``before`` (-> messages published before its first recorded one: a realtime loop does not
    wait for the recorder, as with ``ros2 bag record``), ``after`` (topic of `EVERY_TICK_TOPICS` -> ticks
    published after its last recorded one),
    ``growth`` (process -> MB per 10 min after the first window) and ``drift`` (p50, p99, p99.9 ->
    `latency_drift` of the windows').

    Raises
    ------
    BenchmarkError
        If a node fails or does not stop cleanly, the run does not end, or its report has no windows.
    """
    from robotino_geom_mpc.bench.dds import read_timing_report
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import NodeFailed, NodeGroup, node_arguments

    window_s = window_length(duration_s)
    report, bag = folder / "plant_timing.json", folder / "bag"
    args = node_arguments("paper-circle", default_params_file(), duration_s, lockstep=False, bag=bag, overrides={
        "plant_node": {"timing_report": str(report), "timing_window_s": window_s}})
    with NodeGroup(log_dir=folder / "logs") as group:
        nodes = {name: group.start(name, argv) for name, argv in args.items()}
        with ProcessSampler({name: node.popen.pid for name, node in nodes.items()}) as sampler:
            try:
                ended = group.wait(nodes["plant_node"], duration_s + _END_MARGIN_S, done=report.exists, poll_s=0.5)
            except NodeFailed as exc:
                raise BenchmarkError(f"soak: {exc}") from None
            if not ended:
                raise BenchmarkError(f"soak: the plant did not end within {duration_s + _END_MARGIN_S:g} s")
        _stop_like_run(group, nodes)
    timing = read_timing_report(report, "realtime")
    windows = [w for w in timing.get("windows", []) if w["end_steady_s"] - w["start_steady_s"] >= 0.5 * window_s]
    if len(windows) < 2:
        raise BenchmarkError(f"soak: the plant's report has {len(windows)} full window(s) of {window_s:g} s")
    origin = windows[0]["start_steady_s"]
    rows = []
    for w in windows:
        row = {"start_s": w["start_steady_s"] - origin, "end_s": w["end_steady_s"] - origin, "ticks": w["ticks"],
               "missed": w["missed"], "latency_ms": w["latency_ms"], "processes": {},
               "load": sampler.window_load(w["start_steady_s"], w["end_steady_s"])}
        for name in nodes:
            figures = sampler.window(name, w["start_steady_s"], w["end_steady_s"])
            if figures is not None:
                row["processes"][name] = figures
        rows.append(row)
    counts = bag_counts(bag)
    sequences = bag_sequences(bag, SEQUENCED_TOPICS)
    later = rows[1:]  # after the warm-up window

    def slope(name: str, key: str) -> float:
        inside = [r for r in later if name in r["processes"]]
        return growth_mb_per_10min([0.5 * (r["start_s"] + r["end_s"]) for r in inside],
                                   [r["processes"][name][key] for r in inside])

    growth = {name: slope(name, "rss_mb") for name in nodes}
    parts = {name: {"anon": slope(name, "anon_mb"), "shmem": slope(name, "shmem_mb")} for name in nodes}
    answered = [r for r in rows if r["latency_ms"] is not None]
    drift = {q: latency_drift([r["latency_ms"][q] for r in answered]) for q in ("p50", "p99", "p99.9")}
    result = {"windows": rows, "ticks": timing["ticks"], "bag": counts, "growth": growth, "growth_parts": parts,
              "drift": drift,
              "short": {topic: per * timing["ticks"] - counts.get(topic, 0) for topic, per in PLANT_TOPICS.items()},
              "lost": {topic: last - first + 1 - n for topic, (n, first, last) in sequences.items()},
              "before": {topic: first - 1 for topic, (_, first, _) in sequences.items()},
              "after": {topic: timing["ticks"] - last for topic, (_, _, last) in sequences.items()
                        if topic in EVERY_TICK_TOPICS},
              "missed": timing["missed"], "window_s": window_s}
    for line in soak_table(result):
        log(line)
    return result


def soak_table(result: dict[str, Any]) -> list[str]:
    """The soak's windows as text lines: time, missed, latency, and RSS / CPU per process."""
    names = sorted({name for row in result["windows"] for name in row["processes"]})
    lines = ["window [s]     load  ticks missed  p50/p99/p99.9 ms     " + "  ".join(f"{n[:16]:>16}" for n in names),
             " " * 53 + "  ".join(f"{'RSS MB / CPU %':>16}" for _ in names)]
    for row in result["windows"]:
        lat = row["latency_ms"] or {}
        cells = [f"{row['processes'][n]['rss_mb']:7.2f} / {row['processes'][n]['cpu_pct']:5.1f}"
                 if n in row["processes"] else f"{'-':>16}" for n in names]
        lines.append(f"{row['start_s']:6.0f}-{row['end_s']:<6.0f} {row['load']:5.1f} {row['ticks']:6d} "
                     f"{row['missed']:6d}  {lat.get('p50', float('nan')):5.2f}/{lat.get('p99', float('nan')):5.2f}/"
                     f"{lat.get('p99.9', float('nan')):5.2f}     " + "  ".join(f"{c:>16}" for c in cells))
    over = [n for n, g in result["growth"].items() if g > GROWTH_BOUND_MB_PER_10MIN]
    lines.append("growth after the first window [MB/10 min]: " + ", ".join(
        f"{n} {g:+.3f}" for n, g in result["growth"].items()) + (
        f": above {GROWTH_BOUND_MB_PER_10MIN:g} for {', '.join(over)}" if over else
        f": all within {GROWTH_BOUND_MB_PER_10MIN:g}"))
    if "growth_parts" in result:
        lines.append("  of which anonymous (heaps) / shared memory (DDS segments touched): " + ", ".join(
            f"{n} {p['anon']:+.3f} / {p['shmem']:+.3f}" for n, p in result["growth_parts"].items()))
    for q, d in result["drift"].items():
        verdict = {None: "no verdict (< 3 windows)", True: "DRIFT", False: "no drift"}[d["drift"]]
        lines.append(f"latency {q}: first {d['first']:.2f} ms, last {d['last']:.2f} ms, change {d['change']:+.2f} ms; "
                     f"step between windows (RMS) {d['step']:.2f} ms; ratio {d['ratio']:.2f}, permutation p "
                     f"{d['p']:.3f}: {verdict} (alpha {DRIFT_ALPHA:g})")
    loads = [row["load"] for row in result["windows"]]
    lines.append(f"machine load (1-min average) in the first and last window: {loads[0]:.1f}, {loads[-1]:.1f}")
    lines.append(f"ticks {result['ticks']}, bag: " + ", ".join(f"{t} {c}" for t, c in sorted(result["bag"].items())))
    lines.append("lost between the first and last recorded (sequence numbers): " + ", ".join(
        f"{t} {n}" for t, n in result["lost"].items()) + "; published before the recording: " + ", ".join(
        f"{t} {n}" for t, n in result["before"].items()))
    return lines


def run_loop(runs: int, folder: Path, log: Callable[[str], None], duration_s: float = RUN_S) -> dict[str, float]:
    """``robotino-geom-mpc run`` `runs` times in a row (`end_to_end.timed_run`); the failures and the wall times.

    Every run is made; `BenchmarkError` at the end if any failed (the first failure's message).
    """
    from robotino_geom_mpc.bench.end_to_end import timed_run

    walls, failures = [], []
    for k in range(runs):
        try:
            walls.append(timed_run(folder / f"run{k}", duration_s=duration_s)["run_end_to_end_s"])
        except BenchmarkError as exc:
            failures.append(f"run {k + 1}: {exc}")
            log(f"soak: run {k + 1} of {runs} failed: {exc}")
        if (k + 1) % 10 == 0:
            log(f"soak: {k + 1} runs, {len(failures)} failed")
    if failures:
        raise BenchmarkError(f"{len(failures)} of {runs} runs failed; the first: {failures[0]}")
    return {"soak_runs": runs, "soak_runs_failed": 0, "soak_run_wall_s_median": statistics.median(walls),
            "soak_run_wall_s_max": max(walls)}


def _flat(result: dict[str, Any]) -> dict[str, float]:
    """The soak's figures as the registry's flat keys (``soak_wK_...`` per window K)."""
    out: dict[str, float] = {"soak_window_s": result["window_s"], "soak_ticks": result["ticks"],
                             "soak_missed_ticks": result["missed"]}
    for k, row in enumerate(result["windows"]):
        out[f"soak_w{k}_missed_ticks"] = row["missed"]
        out[f"soak_w{k}_load"] = row["load"]
        for q, value in (row["latency_ms"] or {}).items():
            out[f"soak_w{k}_latency_{q.replace('.', '_')}_ms"] = value
        for name, figures in row["processes"].items():
            out[f"soak_w{k}_rss_mb_{name}"] = figures["rss_mb"]
            out[f"soak_w{k}_cpu_pct_{name}"] = figures["cpu_pct"]
    for name, slope in result["growth"].items():
        out[f"soak_rss_growth_abs_mb_per_10min_{name}"] = abs(slope)
    for name, parts in result.get("growth_parts", {}).items():
        for part, slope in parts.items():
            out[f"soak_{part}_growth_abs_mb_per_10min_{name}"] = abs(slope)
    for q, d in result["drift"].items():
        for key in ("change", "ratio", "p"):
            out[f"soak_latency_{q.replace('.', '_')}_drift_{key}"] = abs(d[key]) if key == "change" else d[key]
    for topic, count in result["bag"].items():
        out[f"soak_bag_count_{topic.strip('/').replace('/', '_')}"] = count
    for key in ("lost", "before", "after", "short"):
        for topic, n in result[key].items():
            out[f"soak_bag_{key}_{topic.strip('/').replace('/', '_')}"] = abs(n)
    return {key: value for key, value in out.items() if value == value}  # NaN (too few windows) left out


@benchmark("soak", "the realtime loop with the recorder for --duration S (30 min) per window, 200 controller "
           "kills and restarts, 100 runs in a row (not in a plain bench)", default=False, takes_duration=True)
def bench_soak(quick: bool, duration_s: float | None = None) -> dict[str, float]:
    """`soak`, `restarts.restart_loop` and `run_loop`, in that order; see the module docstring."""
    try:
        import rclpy  # noqa: F401  (the nodes need it)
    except ImportError as exc:
        raise BenchmarkSkipped(f"ROS 2 not available: {exc}") from None
    from robotino_geom_mpc.bench.restarts import restart_loop

    def log(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    duration = duration_s if duration_s is not None else (60.0 if quick else SOAK_S)
    with tempfile.TemporaryDirectory(prefix="robotino_soak_") as tmp:
        log(f"soak: the realtime loop with the recorder for {duration:g} s")
        out = _flat(soak(duration, Path(tmp) / "soak", log))
        log(f"soak: {5 if quick else RESTARTS} controller kills and restarts")
        out.update(restart_loop(5 if quick else RESTARTS, Path(tmp) / "restarts", log))
        log(f"soak: {5 if quick else RUNS} runs in a row")
        out.update(run_loop(5 if quick else RUNS, Path(tmp) / "runs", log))
    return out
