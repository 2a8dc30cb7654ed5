"""A recorded run across two hosts (`system.netns`): the plant on one, the others on the other, read from the bag.

The nodes get exactly the arguments ``run`` gives them (`system.processes.node_arguments`: with a scenario's
link, the plant's emulated radio link and the controller's delay-compensated plans; `plans` False is
``run --no-compensation``), the plant's timing report in the run's folder, and DDS over UDP between the hosts
(`Hosts.dds_environment`). Used by test_two_hosts.py and the ``networked`` benchmark.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robotino_geom_mpc.bench.dds import read_timing_report
from robotino_geom_mpc.offline.results import RunData
from robotino_geom_mpc.system.netns import Hosts, run_across_hosts

__all__ = ["TwoHostsRun", "two_hosts_run"]


@dataclass(frozen=True)
class TwoHostsRun:
    """A run across two hosts: the run read from its bag, the bag, the bytes received on the plant's and the
    controller's end of the veth meanwhile, and the plant's timing report (`bench.dds.read_timing_report`).
    """

    run: RunData
    bag: Path
    plant_received_bytes: int
    controller_received_bytes: int
    timing: dict[str, Any]


def two_hosts_run(hosts: Hosts, out: str | os.PathLike, scenario: str, duration_s: float, lockstep: bool,
                  plans: bool | None = None) -> TwoHostsRun:
    """Run `scenario` for `duration_s` across `hosts` with the default parameters, recorded on the controller's
    host in `out`/bag (node logs in `out`/logs); `plans` as `node_arguments`'s (None: with the scenario's link).

    Raises
    ------
    NodeFailed
        If a node fails or the run does not end (`run_across_hosts`).
    BenchmarkError
        If the plant wrote no valid timing report.
    BagError
        If the bag lacks a run's topics.
    """
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.recording.report import run_data_from_bag
    from robotino_geom_mpc.system.processes import node_arguments

    out = Path(out)
    params = default_params_file()
    bag, report = out / "bag", out / "timing.json"
    env = hosts.dds_environment()
    args = node_arguments(scenario, params, duration_s, lockstep, bag=bag, plans=plans,
                          overrides={"plant_node": {"timing_report": str(report)}}, environ={**os.environ, **env})
    plant_rx, controller_rx = run_across_hosts(hosts, args, out / "logs", 60.0 + 20.0 * duration_s, env)
    timing = read_timing_report(report, "lockstep" if lockstep else "realtime")
    return TwoHostsRun(run_data_from_bag(bag, params, scenario), bag, plant_rx, controller_rx, timing)
