"""The control loop over DDS, measured: lockstep real-time factor, realtime missed ticks and latency.

Both functions start the three nodes as processes (`processes.NodeGroup`)
on the current ROS_DOMAIN_ID and take the figures from the plant's own
report, so no probe subscribes the loop (an extra reader of /clock or the
odometry costs the plant a wake-up of one more process per tick):

* `bench_lockstep`: the plant in lockstep on a scenario; the real-time
  factor is simulated time over the wall time from the command of tick 0
  to that of the last tick (startup and discovery excluded);
* `bench_realtime`: the plant in realtime at the control rate; per tick the
  controller's answer is the first command after the odometry: a tick is
  missed when none arrives before the next odometry; the latency runs from
  publishing the odometry to receiving the command, on the plant's steady
  clock (`robotino_sim_node.loop_timing`): transport on both legs, the
  controller's step and both executors' wake-ups count. On Linux the run's
  host steal (`host_steal`) is sampled beside it, and the missed ticks
  during which the hypervisor took CPU time are counted.

"""

from __future__ import annotations

import os
import re
from typing import Any

import numpy as np


from robotino_geom_mpc.bench.host_steal import StealSampler
from robotino_geom_mpc.core.params import default_params_file, load_params
from robotino_geom_mpc.ros.processes import LOCKSTEP_WAIT_FOR, NodeGroup, ros_args

__all__ = ["LOCKSTEP_RUNS", "lockstep_nodes", "bench_lockstep", "bench_realtime", "dds_benchmarks", "missed_ticks",
           "realtime_report"]

# the plant's reports at the end of a run (`PlantNode._report_run`, `LoopTiming.summary`)
_RUN_OVER = re.compile(r"run over: (\d+) ticks; ticks 1-\d+ \(([0-9.e+-]+) s simulated\) in ([0-9.e+-]+) s")
_REALTIME_OVER = re.compile(r"realtime run over: (\d+) ticks answered, (\d+) missed; odometry-to-command latency "
                            r"median ([0-9.]+) ms, p99 ([0-9.]+) ms, max ([0-9.]+) ms")
_FIRST_ANSWER = re.compile(r"first answer at steady time ([0-9.]+) s")
_MISSED_TICK = re.compile(r"([0-9.]+): ([0-9.]+)")  # in the list after "to the next odometry)"

def lockstep_nodes(
    group: NodeGroup,
    scenario: str,
    duration_s: float,
    params_file: str | os.PathLike | None = None,
    wait_for: list[str] | None = None,
    realtime: bool = False,
    plant_overrides: dict[str, Any] | None = None,
    trajectory_overrides: dict[str, Any] | None = None,
):
    """Start trajectory, controller and plant (lockstep unless `realtime`); returns the plant's process.

    `wait_for` is the plant's ``lockstep_wait_for`` (`LOCKSTEP_WAIT_FOR`, the
    three nodes, when None): add the subscriptions of any other node that
    must see tick 0 (a probe, the recorder).
    """
    params_file = params_file or default_params_file()
    mode = "realtime" if realtime else "lockstep"
    # neither reads its node clock in the loop: the trajectory's time is the /clock messages, the controller's
    # the odometry stamps
    group.start("trajectory_node", ros_args(params_file, {"scenario": scenario, "mode": mode,
                                                         **(trajectory_overrides or {})}))
    group.start("controller_node", ros_args(params_file, {"mode": mode}))
    return group.start(
        "plant_node",
        ros_args(params_file, {
            "mode": mode,
            "duration_s": float(duration_s),
            "lockstep_wait_for": list(wait_for or LOCKSTEP_WAIT_FOR),
            **(plant_overrides or {}),
        }),
    )


def bench_lockstep(scenario: str = "paper-circle", duration_s: float = 10.0, timeout_s: float = 300.0) -> dict:
    """Run the lockstep loop; returns ``{"lockstep_dds_realtime_factor": ..., "ticks": ..., "host_steal_ms": ...}``.

    The figure is the plant's own (its "run over" log line): the simulated
    time of ticks 1 .. n - 1 over the wall time from receiving the command of
    tick 0 to receiving that of the last tick. So startup and discovery do
    not count (tick 0 is answered once the last endpoints have matched, which
    can take a Fast DDS announcement period). ``host_steal_ms`` (where the
    machine reports it, `host_steal`) is the CPU time the hypervisor took
    during the whole run, startup included.
    """
    with StealSampler(interval_s=0.1) as steal, NodeGroup() as group:
        plant = lockstep_nodes(group, scenario, duration_s)
        if not group.wait(plant, timeout_s):
            raise TimeoutError(f"lockstep run of {duration_s} s did not end within {timeout_s} s")
        match = _RUN_OVER.search(plant.stderr_tail(lines=50))
    if match is None:
        raise RuntimeError("the plant did not report the end of the lockstep run")
    ticks, simulated, wall = int(match[1]), float(match[2]), float(match[3])
    out = {"lockstep_dds_realtime_factor": simulated / wall, "ticks": ticks}
    if steal.available:
        out["host_steal_ms"] = 1e3 * steal.total_s()
    return out


def bench_realtime(duration_s: float = 60.0, scenario: str = "paper-circle", timeout_s: float | None = None) -> dict:
    """Run the realtime loop for `duration_s`; missed ticks and odometry-to-command latency (median, p99) in ms.

    The figures are the plant's own ("realtime run over" log line, `robotino_sim_node.loop_timing`): from
    the first answered tick on, the time from publishing a tick's odometry to receiving its command, on
    the plant's steady clock; no probe subscribes the loop. Where the machine reports steal time
    (`host_steal`), the run's steal and the missed ticks during which the host took CPU time are added.
    """
    period_s = load_params()[1].period_s
    with StealSampler() as steal, NodeGroup() as group:
        plant = lockstep_nodes(group, scenario, duration_s, realtime=True)
        if not group.wait(plant, timeout_s or duration_s + 60.0):
            raise TimeoutError(f"realtime run of {duration_s} s did not end")
        report = plant.stderr_tail(lines=50)
    summary = realtime_report(report)
    if summary is None:
        raise RuntimeError("the plant did not report the end of the realtime run")
    out = {
        "realtime_missed_ticks": summary["missed"],
        "realtime_ticks": summary["answered"] + summary["missed"],
        "realtime_expected_ticks": int(round(duration_s / period_s)),
        "realtime_latency_median_ms": summary["median_ms"],
        "realtime_latency_p99_ms": summary["p99_ms"],
        "realtime_latency_max_ms": summary["max_ms"],
    }
    if steal.available:
        out["realtime_host_steal_ms"] = 1e3 * steal.total_s()
        out["realtime_missed_ticks_in_host_steal"] = sum(
            steal.during(t - period_s, t + gap) > 0.0 for t, gap in missed_ticks(report))
    return out


def realtime_report(report: str) -> dict[str, Any] | None:
    """The plant's realtime summary line (`LoopTiming.summary`) read back, or None.

    None if the report lacks the line or no tick was answered (the latencies read nan). Keys:
    ``answered``, ``missed`` (ticks), ``median_ms``, ``p99_ms``, ``max_ms`` (latency) and
    ``first_answer_s`` (steady time of the first answer; None if the line does not give it).
    """
    match = _REALTIME_OVER.search(report)
    if match is None:
        return None
    first = _FIRST_ANSWER.search(report)
    return {"answered": int(match[1]), "missed": int(match[2]), "median_ms": float(match[3]),
            "p99_ms": float(match[4]), "max_ms": float(match[5]), "first_answer_s": float(first[1]) if first else None}


def missed_ticks(report: str) -> list[tuple[float, float]]:
    """The missed ticks the plant's realtime report lists: (steady time of their odometry [s], time to the next [s]).

    The report lists at most `loop_timing.MISSES_KEPT` of them, timed from the first answer.
    """
    line = next((ln for ln in report.splitlines() if "realtime run over:" in ln), "")
    first = _FIRST_ANSWER.search(line)
    if first is None or "to the next odometry)" not in line:
        return []
    listed = line.split("to the next odometry)", 1)[1]
    return [(float(first[1]) + float(t), 1e-3 * float(gap)) for t, gap in _MISSED_TICK.findall(listed)]


LOCKSTEP_RUNS = 3  # the lockstep figure is the median of these runs (one with quick)


def dds_benchmarks(quick: bool = False) -> dict[str, float]:
    """The figures `bench` reports: lockstep real-time factor on paper-circle, realtime 100 Hz loop.

    The lockstep factor is the median of `LOCKSTEP_RUNS` runs of 22 s (the
    slowest and fastest are reported too: on a shared 2-core machine single
    runs differ by up to 2x); the realtime figures come from one 60 s run.
    """
    runs = [bench_lockstep(duration_s=5.0 if quick else 22.0) for _ in range(1 if quick else LOCKSTEP_RUNS)]
    factors = [run["lockstep_dds_realtime_factor"] for run in runs]
    out = {
        "lockstep_dds_realtime_factor": float(np.median(factors)),
        "lockstep_dds_realtime_factor_min": min(factors),
        "lockstep_dds_realtime_factor_max": max(factors),
    }
    if all("host_steal_ms" in run for run in runs):
        out["lockstep_host_steal_ms"] = sum(run["host_steal_ms"] for run in runs)
    realtime = bench_realtime(duration_s=10.0 if quick else 60.0)
    out.update({k: v for k, v in realtime.items() if k not in ("realtime_ticks", "realtime_expected_ticks")})
    return out
