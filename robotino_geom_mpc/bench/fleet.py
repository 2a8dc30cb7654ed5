"""Benchmark ``fleet``: N robots in realtime at 100 Hz, the fleet's three processes against N separate loops.

Side by side for each N (1, 5, 10, 20; quick: 1 and 5), the fleet first:

* the fleet: `system.processes.fleet_arguments` (``fleet_trajectory_node``, ``fleet_controller_node``,
  ``fleet_plant_node``: one node per robot in each);
* N separate loops (today's layout): per robot its own trajectory, controller and plant processes in its
  namespace (`system.processes.node_arguments`; no description publisher, and a preview every 10 periods
  (`system.processes.fleet_realtime_parameters`), as in the fleet: the figures compare the layouts).

No recorder. The trajectory and controller processes start first; the plants once both have logged that they
are ready (so every plant's run spans the window). Once every plant is ready too and `SETTLE_S` later, the CPU time
of every process (``/proc/PID/stat``) is read at the start and the end of a `WINDOW_S` window; each plant reports
its loop per second (``timing_window_s`` 1, `robotino_sim_node.loop_timing`), and the ticks and misses of the
one-second windows within the window are counted. Figures per N: ``fleet_n<N>_cpu_pct_per_robot`` and
``separate_n<N>_cpu_pct_per_robot`` (% of one core per robot: all the processes' CPU over the window, / N),
``fleet_n<N>_missed_pct`` and ``separate_n<N>_missed_pct`` (missed ticks of all robots, % of their ticks).
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path
from typing import Any

from robotino_geom_mpc.bench.recorder_load import process_cpu_s
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.bench.registry import BenchmarkError, BenchmarkSkipped, benchmark
from robotino_geom_mpc.system.signals import NODE_MODULES
from robotino_geom_mpc.system.processes import NodeFailed, NodeGroup, NodeProcess, fleet_arguments, \
    fleet_realtime_parameters, node_arguments, robot_names

__all__ = ["FLEET_SIZES", "SETTLE_S", "WINDOW_S", "bench_fleet", "fleet_side", "separate_side"]

FLEET_SIZES = (1, 5, 10, 20)
WINDOW_S = 10.0  # quick: 4 s
SETTLE_S = 2.0  # after the last plant is ready: its first odometries matched, the references started
START_LIMIT_S = 180.0  # every process of a side ready within this (N = 20 separate: 60 Python processes)
READY = {"trajectory": "trajectory '", "controller": "controller ready", "plant": "plant simulator ready"}
SCENARIO = "paper-circle"


def _ready(node: NodeProcess, line: str, count: int) -> bool:
    """Whether `node` logged `line` (its nodes' ready line) `count` times."""
    return node.stderr_path.read_text(errors="replace").count(line) + \
        node.stdout_path.read_text(errors="replace").count(line) >= count


def _wait_ready(group: NodeGroup, nodes: list[tuple[NodeProcess, str, int]], deadline: float, what: str) -> None:
    while not all(_ready(node, line, count) for node, line, count in nodes):
        if time.monotonic() > deadline:
            raise BenchmarkError(f"fleet: {what} not ready within {START_LIMIT_S:g} s")
        try:
            group.check()
        except NodeFailed as exc:
            raise BenchmarkError(f"fleet: {what}: {exc}") from None
        time.sleep(0.1)


def _window_counts(report: dict[str, Any], start: float, end: float) -> tuple[int, int]:
    """(ticks, missed) of a realtime plant report's one-second windows within steady [start, end]."""
    ticks = missed = 0
    for window in report.get("windows") or []:
        if window["start_steady_s"] >= start and window["end_steady_s"] <= end:
            ticks += window["ticks"]
            missed += window["missed"]
    return ticks, missed


def _measure(group: NodeGroup, first: dict[str, list[str]], plants: dict[str, list[str]], robots: int,
             reports: list[Path], window_s: float) -> dict[str, float]:
    """Start `first`, then `plants` once `first` is ready; CPU and misses over the window (module docstring)."""
    deadline = time.monotonic() + START_LIMIT_S
    started = {name: group.start(name, argv, NODE_MODULES[name.split("@")[0]]) for name, argv in first.items()}
    _wait_ready(group, [(node, READY[kind], count) for node, kind, count in _kinds(started, robots)], deadline,
                "the trajectories and controllers")
    plant_nodes = {name: group.start(name, argv, NODE_MODULES[name.split("@")[0]]) for name, argv in plants.items()}
    _wait_ready(group, [(node, READY["plant"], robots if len(plant_nodes) == 1 else 1)
                        for node in plant_nodes.values()], deadline, "the plants")
    time.sleep(SETTLE_S)
    pids = [node.popen.pid for node in [*started.values(), *plant_nodes.values()]]
    start, before = time.monotonic(), [process_cpu_s(pid) for pid in pids]
    time.sleep(window_s)
    end, after = time.monotonic(), [process_cpu_s(pid) for pid in pids]
    for node in plant_nodes.values():  # each writes its report at the end of its run
        if not group.wait(node, START_LIMIT_S + window_s):
            raise BenchmarkError(f"fleet: {node.name} did not end its run")
    ticks = missed = 0
    for path in reports:
        report = json.loads(path.read_text())
        for each in (report.values() if "mode" not in report else [report]):  # the fleet's: per robot
            t, m = _window_counts(each, start, end)
            ticks, missed = ticks + t, missed + m
    if ticks == 0:
        raise BenchmarkError("fleet: no tick counted in the window")
    cpu = sum(after) - sum(before)
    return {"cpu_pct_per_robot": 100.0 * cpu / (end - start) / robots, "missed_pct": 100.0 * missed / ticks}


def _kinds(started: dict[str, NodeProcess], robots: int) -> list[tuple[NodeProcess, str, int]]:
    """(process, kind, ready lines due) of the trajectory and controller processes (a fleet's: one per robot)."""
    out = []
    for name, node in started.items():
        kind = "trajectory" if "trajectory" in name else "controller"
        out.append((node, kind, robots if name.startswith("fleet_") else 1))
    return out


def _plant_params(duration_s: float, report: Path) -> dict[str, Any]:
    return {"timing_report": str(report), "timing_window_s": 1.0, "duration_s": duration_s}


def fleet_side(robots: int, params: Path, tmp: Path, window_s: float) -> dict[str, float]:
    """The fleet's three processes: per-robot CPU and missed ticks over the window."""
    report = tmp / "fleet_timing.json"
    duration = SETTLE_S + window_s + 5.0  # the plants start together: their runs span the window
    args = fleet_arguments(SCENARIO, params, duration, False, robots,
                           overrides={"plant_node": _plant_params(duration, report)})
    plants = {"fleet_plant_node": args.pop("fleet_plant_node")}
    with NodeGroup(log_dir=tmp / "fleet") as group:
        return _measure(group, args, plants, robots, [report], window_s)


def separate_side(robots: int, params: Path, tmp: Path, window_s: float) -> dict[str, float]:
    """N separate loops (three processes per robot): per-robot CPU and missed ticks over the window."""
    first: dict[str, list[str]] = {}
    plants: dict[str, list[str]] = {}
    reports = []
    _, control = load_params(params)
    # the plants start one after the other: the first's run must span the last's start, the settle and the window
    duration = SETTLE_S + window_s + 5.0 + 2.0 * robots
    for namespace in robot_names(robots):
        report = tmp / f"{namespace}_timing.json"
        reports.append(report)
        args = node_arguments(SCENARIO, params, duration, False, namespace=namespace,
                              overrides={**fleet_realtime_parameters(control.period_s),
                                         "plant_node": _plant_params(duration, report)})
        first[f"trajectory_node@{namespace}"] = args["trajectory_node"]
        first[f"controller_node@{namespace}"] = args["controller_node"]
        plants[f"plant_node@{namespace}"] = args["plant_node"]
    with NodeGroup(log_dir=tmp / "separate") as group:
        return _measure(group, first, plants, robots, reports, window_s)


def bench_fleet(sizes: tuple[int, ...] = FLEET_SIZES, window_s: float = WINDOW_S) -> dict[str, float]:
    """Per N of `sizes`: the fleet's and the separate loops' per-robot CPU [% of a core] and missed ticks [%]."""
    from robotino_geom_mpc.params.presets import default_params_file

    params = default_params_file()
    figures: dict[str, float] = {}
    for robots in sizes:
        for side, measure in (("fleet", fleet_side), ("separate", separate_side)):
            with tempfile.TemporaryDirectory(prefix=f"bench_fleet_{side}_") as tmp:
                for key, value in measure(robots, params, Path(tmp), window_s).items():
                    figures[f"{side}_n{robots}_{key}"] = value
    return figures


@benchmark("fleet", "N robots in realtime: the fleet's processes against N separate loops (CPU, missed ticks)",
           default=False)
def _fleet(quick: bool) -> dict[str, float]:
    if not Path("/proc/self/stat").exists():
        raise BenchmarkSkipped("no /proc: the processes' CPU time cannot be read")
    return bench_fleet((1, 5) if quick else FLEET_SIZES, 4.0 if quick else WINDOW_S)
