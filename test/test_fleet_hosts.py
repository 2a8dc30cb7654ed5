"""A fleet across two hosts: the fleet plant in one Linux network namespace, the fleet trajectory, the fleet controller
and the recorder in another (`system.netns`, as test_two_hosts.py runs one robot).

Three robots, with the arguments ``run --robots 3`` gives (`processes.fleet_arguments`) and DDS over UDP between
the hosts (`Hosts.dds_environment`); the run ends as `system.netns.run_across_hosts` ends one robot's. Each robot's
metrics are read from its namespace of the one bag as ``run`` reads them. Lockstep: each robot's equal its
single-robot run (`simulation.run_scenario`) to 1e-9. Realtime: each robot tracks paper-circle as the single robot
across the hosts does (test_two_hosts's limit and load guard). Every robot's commands crossed the veth. Needs root
(``ip netns``); skipped otherwise.
"""

from __future__ import annotations

import json
import os

import pytest

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.report import report_bag
from robotino_geom_mpc.system.netns import netns_unavailable, run_across_hosts
from robotino_geom_mpc.system.processes import fleet_arguments, robot_names
from test_fleet import DURATION_S, SCENARIO, SEED, _assert_each_robot_is_the_single_run
from test_two_hosts import REALTIME_RMS_LIMIT_M, _load_guard

pytestmark = [pytest.mark.ros, pytest.mark.slow,
              pytest.mark.skipif(netns_unavailable() is not None, reason=str(netns_unavailable()))]

ROBOTS = 3


def _run(hosts, out, scenario: str, duration_s: float, lockstep: bool, seed: int = 0) -> dict:
    """The fleet across `hosts`, recorded on the controller's host; each robot's metrics as ``run`` writes them
    (`out`/robot<k>/metrics.json) and the plant's bytes received, the fleet's timing report (`out`/timing.json).
    """
    params = default_params_file()
    env = hosts.dds_environment()
    bag = out / "bag"
    args = fleet_arguments(scenario, params, duration_s, lockstep=lockstep, robots=ROBOTS, seed=seed, bag=bag,
                           overrides={"plant_node": {"timing_report": str(out / "timing.json")}},
                           environ={**os.environ, **env})
    plant_rx, _ = run_across_hosts(hosts, args, out / "logs", 60.0 + 20.0 * duration_s * ROBOTS, env,
                                   plant="fleet_plant_node")
    reader = BagReader(bag)
    metrics = {ns: report_bag(reader.in_namespace(ns), out / ns, params, plots=False) for ns in robot_names(ROBOTS)}
    return {"plant_rx": plant_rx, "metrics": metrics, "timing": json.loads((out / "timing.json").read_text())}


def test_lockstep_fleet_across_two_network_namespaces_each_robot_is_the_single_robot_run(hosts, tmp_path):
    _, control = load_params()
    done = _run(hosts, tmp_path, SCENARIO, DURATION_S, lockstep=True, seed=SEED)
    _assert_each_robot_is_the_single_run(tmp_path, ROBOTS)
    # every tick's three voltages of every robot (a Float64MultiArray, > 100 bytes each) crossed to the plant's host
    assert done["plant_rx"] > 100 * ROBOTS * round(DURATION_S / control.period_s), done["plant_rx"]


def test_realtime_fleet_across_two_network_namespaces_tracks_paper_circle(hosts, tmp_path):
    _, control = load_params()
    duration_s = 4.0
    done = _run(hosts, tmp_path, "paper-circle", duration_s, lockstep=False)
    ticks = sum(timing["ticks"] for timing in done["timing"].values())
    assert done["plant_rx"] > 100 * ticks, (done["plant_rx"], ticks)
    for namespace in robot_names(ROBOTS):
        timing, rms = done["timing"][namespace], done["metrics"][namespace]["rms_position_error_m"]
        print(f"\n{namespace}: {timing['answered']} ticks answered, {timing['missed']} missed; RMS {rms:.3g} m")
        assert timing["answered"] > timing["missed"], (namespace, timing)
        assert timing["latency_ms"]["median"] < 1e3 * control.period_s, (namespace, timing["latency_ms"])
    for namespace in robot_names(ROBOTS):
        _load_guard(done["timing"][namespace])
        assert done["metrics"][namespace]["rms_position_error_m"] < REALTIME_RMS_LIMIT_M, namespace
