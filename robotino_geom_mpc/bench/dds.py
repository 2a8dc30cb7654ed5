"""The control loop over DDS, measured: lockstep real-time factor, realtime missed ticks and latency, bare round trip.

Both loop functions start the three nodes as processes (`processes.NodeGroup`)
on the current ROS_DOMAIN_ID and take the figures from the plant's own timing
report (the JSON object its ``timing_report`` parameter names, written at the
end of the run), so no probe subscribes the loop (an extra reader of /clock or
the odometry costs the plant a wake-up of one more process per tick):

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

`dds_benchmarks` interleaves them with the bare round trip of `roundtrip`
(the same transport and executors without any control work) and sets the
loop's figures beside it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from robotino_geom_mpc.bench.host_steal import StealSampler
from robotino_geom_mpc.bench.registry import BenchmarkError, wait_for_run
from robotino_geom_mpc.bench.roundtrip import bench_roundtrip
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.system.processes import LOCKSTEP_WAIT_FOR, TIMING_REPORT, NodeGroup, node_arguments

__all__ = ["LOCKSTEP_RUNS", "ROUNDTRIPS", "lockstep_nodes", "bench_lockstep", "bench_realtime",
           "dds_benchmarks", "missed_ticks", "read_timing_report"]

# the keys of the plant's timing report and the types of their values (None: may be null)
_REPORT_KEYS: dict[str, tuple[type, ...]] = {
    "mode": (str,), "ticks": (int,), "loop_ticks": (int,), "simulated_s": (int, float), "wall_s": (int, float),
    "realtime_factor": (int, float, type(None)), "plant_busy_ms_per_tick": (int, float),
    "wait_ms_per_tick": (int, float), "tick0_answer_s": (int, float, type(None)), "answered": (int,),
    "missed": (int,), "latency_ms": (dict, type(None)), "first_answer_steady_s": (int, float, type(None)),
    "missed_ticks": (list,),
}


def lockstep_nodes(
    group: NodeGroup,
    scenario: str,
    duration_s: float,
    params_file: str | os.PathLike | None = None,
    wait_for: list[str] | None = None,
    realtime: bool = False,
    plant_overrides: dict[str, Any] | None = None,
    trajectory_overrides: dict[str, Any] | None = None,
    timing_report: str | os.PathLike | None = None,
    controller_overrides: dict[str, Any] | None = None,
):
    """Start trajectory, controller and plant (lockstep unless `realtime`); returns the plant's process.

    `wait_for` is the plant's ``lockstep_wait_for`` (`LOCKSTEP_WAIT_FOR`, the
    three nodes, when None): add the subscriptions of any other node that
    must see tick 0 (a probe, the recorder). `timing_report` is the plant's
    parameter of that name: the file it writes its timing report to at the
    end of the run (`read_timing_report`).
    """
    report = {} if timing_report is None else {"timing_report": str(timing_report)}
    args = node_arguments(scenario, params_file or default_params_file(), duration_s, not realtime,
                          wait_for=list(wait_for or LOCKSTEP_WAIT_FOR),
                          overrides={"plant_node": {**report, **(plant_overrides or {})},
                                     "trajectory_node": trajectory_overrides or {},
                                     "controller_node": controller_overrides or {}})
    started = {name: group.start(name, argv) for name, argv in args.items()}
    return started["plant_node"]


def read_timing_report(path: str | os.PathLike, mode: str) -> dict[str, Any]:
    """The plant's timing report of a `mode` run (``"lockstep"`` or ``"realtime"``), checked.

    The plant writes one JSON object at the end of the run: ``mode``, ``ticks``, ``loop_ticks`` (ticks 1 ..
    n - 1, timed), ``simulated_s`` and ``wall_s`` of them, ``realtime_factor`` (null with one tick),
    ``plant_busy_ms_per_tick``, ``wait_ms_per_tick``, ``tick0_answer_s``, and of a realtime run ``answered``,
    ``missed``, ``latency_ms`` (``median``, ``p99``, ``max``; null without an answer),
    ``first_answer_steady_s`` and ``missed_ticks`` (``[s after the first answer, s to the next odometry]``,
    the first `loop_timing.MISSES_KEPT`).

    Raises
    ------
    BenchmarkError
        If the file is missing or not JSON, a key is missing or holds a value of another type, or the
        report is of another mode.
    """
    try:
        report = json.loads(Path(path).read_text())
    except OSError as exc:
        raise BenchmarkError(f"the plant wrote no timing report {path} ({exc.strerror})") from None
    except ValueError as exc:
        raise BenchmarkError(f"the plant's timing report {path} is not JSON: {exc}") from None
    if not isinstance(report, dict):
        raise BenchmarkError(f"the plant's timing report {path} is not a JSON object")
    bad = [key for key, types in _REPORT_KEYS.items()
           if key not in report or isinstance(report[key], bool) or not isinstance(report[key], types)]
    latency = report.get("latency_ms")
    if isinstance(latency, dict) and not all(isinstance(latency.get(k), (int, float))
                                             for k in ("median", "p99", "max")):
        bad.append("latency_ms")
    if bad:
        raise BenchmarkError(f"the plant's timing report {path} lacks or mistypes {', '.join(bad)}")
    if report["mode"] != mode:
        raise BenchmarkError(f"the plant's timing report {path} is of a {report['mode']} run, not {mode}")
    return report


def bench_lockstep(scenario: str = "paper-circle", duration_s: float = 10.0, timeout_s: float = 300.0) -> dict:
    """Run the lockstep loop; the plant's real-time factor and wall time per tick, and the host's steal.

    Returns ``lockstep_dds_realtime_factor`` (the plant's: the simulated time of ticks 1 .. n - 1 over
    the wall time from receiving the command of tick 0 to receiving that of the last tick, so startup
    and discovery do not count: tick 0 is answered once the last endpoints have matched, which can take
    a Fast DDS announcement period), ``lockstep_tick_us`` (that wall time per tick), ``ticks`` and,
    where the machine reports it (`host_steal`), ``host_steal_ms``: the CPU time the hypervisor took
    during the whole run, startup included.

    Raises
    ------
    BenchmarkError
        If a node fails, the run does not end in `timeout_s`, or its timing report is missing or has no
        loop to time (one tick).
    """
    with StealSampler(interval_s=0.1) as steal, NodeGroup() as group:
        path = group.logs / TIMING_REPORT
        plant = lockstep_nodes(group, scenario, duration_s, timing_report=path)
        wait_for_run(group, plant, timeout_s, f"lockstep run of {duration_s} s")
        report = read_timing_report(path, "lockstep")
    if report["realtime_factor"] is None or report["loop_ticks"] < 1:
        raise BenchmarkError(f"the lockstep run of {duration_s} s had {report['ticks']} tick: no loop to time")
    out = {"lockstep_dds_realtime_factor": report["realtime_factor"],
           "lockstep_tick_us": 1e6 * report["wall_s"] / report["loop_ticks"], "ticks": report["ticks"]}
    if steal.available:
        out["host_steal_ms"] = 1e3 * steal.total_s()
    return out


def bench_realtime(duration_s: float = 60.0, scenario: str = "paper-circle", timeout_s: float | None = None) -> dict:
    """Run the realtime loop for `duration_s`; missed ticks and odometry-to-command latency (median, p99) in ms.

    The figures are the plant's own (its timing report, `robotino_sim_node.loop_timing`): from the first
    answered tick on, the time from publishing a tick's odometry to receiving its command, on the
    plant's steady clock; no probe subscribes the loop. Where the machine reports steal time
    (`host_steal`), the run's steal and the missed ticks during which the host took CPU time are added.

    Raises
    ------
    BenchmarkError
        If a node fails, the run does not end in time, or its timing report is missing or has no answer.
    """
    period_s = load_params()[1].period_s
    with StealSampler() as steal, NodeGroup() as group:
        path = group.logs / TIMING_REPORT
        plant = lockstep_nodes(group, scenario, duration_s, realtime=True, timing_report=path)
        wait_for_run(group, plant, timeout_s or duration_s + 60.0, f"realtime run of {duration_s} s")
        report = read_timing_report(path, "realtime")
    latency = report["latency_ms"]
    if latency is None:
        raise BenchmarkError(f"no tick of the realtime run of {duration_s} s was answered")
    out = {
        "realtime_missed_ticks": report["missed"],
        "realtime_ticks": report["answered"] + report["missed"],
        "realtime_expected_ticks": int(round(duration_s / period_s)),
        "realtime_latency_median_ms": latency["median"],
        "realtime_latency_p99_ms": latency["p99"],
        "realtime_latency_max_ms": latency["max"],
    }
    if steal.available:
        out["realtime_host_steal_ms"] = 1e3 * steal.total_s()
        out["realtime_missed_ticks_in_host_steal"] = sum(
            steal.during(t - period_s, t + gap) > 0.0 for t, gap in missed_ticks(report))
    return out


def missed_ticks(report: dict[str, Any]) -> list[tuple[float, float]]:
    """The missed ticks a realtime timing report lists: (steady time of their odometry [s], time to the next [s]).

    The report lists at most `loop_timing.MISSES_KEPT` of them, timed from the first answer.
    """
    first = report["first_answer_steady_s"]
    if first is None:
        return []
    return [(first + after, gap) for after, gap in report["missed_ticks"]]


LOCKSTEP_RUNS = 3  # the lockstep figure is the median of these runs (one with quick)
ROUNDTRIPS = 5000  # bare round trips per run beside each lockstep run and after the realtime run (quick: 1000)


def dds_benchmarks(quick: bool = False) -> dict[str, float]:
    """The figures `bench` reports: lockstep real-time factor on paper-circle, realtime 100 Hz loop, round trip.

    The lockstep factor is the median of `LOCKSTEP_RUNS` runs of 22 s (the
    slowest and fastest are reported too: on a shared 2-core machine single
    runs differ by up to 2x); the realtime figures come from one 60 s run.
    A bare round trip (`roundtrip.bench_roundtrip`, `ROUNDTRIPS`) follows
    each of these runs; its median and p99 are the medians over those runs.
    ``lockstep_tick_over_roundtrip`` is the median lockstep wall time per
    tick over the median round trip (the lockstep tick cannot be shorter
    than one round trip); ``realtime_latency_p99_over_roundtrip_p99`` sets
    the realtime loop's latency p99 beside the round trip's.
    """
    count = 1000 if quick else ROUNDTRIPS
    runs, trips = [], []
    for _ in range(1 if quick else LOCKSTEP_RUNS):
        runs.append(bench_lockstep(duration_s=5.0 if quick else 22.0))
        trips.append(bench_roundtrip(count=count))
    realtime = bench_realtime(duration_s=10.0 if quick else 60.0)
    trips.append(bench_roundtrip(count=count))
    factors = [run["lockstep_dds_realtime_factor"] for run in runs]
    tick_us = float(np.median([run["lockstep_tick_us"] for run in runs]))
    roundtrip_median = float(np.median([trip["roundtrip_us_median"] for trip in trips]))
    roundtrip_p99 = float(np.median([trip["roundtrip_us_p99"] for trip in trips]))
    out = {
        "lockstep_dds_realtime_factor": float(np.median(factors)),
        "lockstep_dds_realtime_factor_min": min(factors),
        "lockstep_dds_realtime_factor_max": max(factors),
        "lockstep_tick_us": tick_us,
        "roundtrip_us_median": roundtrip_median,
        "roundtrip_us_p99": roundtrip_p99,
        "lockstep_tick_over_roundtrip": tick_us / roundtrip_median,
    }
    if all("host_steal_ms" in run for run in runs):
        out["lockstep_host_steal_ms"] = sum(run["host_steal_ms"] for run in runs)
    out.update({k: v for k, v in realtime.items() if k not in ("realtime_ticks", "realtime_expected_ticks")})
    out["realtime_latency_p99_over_roundtrip_p99"] = 1e3 * realtime["realtime_latency_p99_ms"] / roundtrip_p99
    return out
