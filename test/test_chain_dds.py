"""The chain over DDS: the plant node as driver + firmware (``chain.active``), `identify --ros` against it, and
the nodes' refusals. Realtime: a host too loaded to run the emulation at wall-clock speed fails these (the plant
logs its late passes)."""

import json
import subprocess
import sys

import pytest

from robotino_geom_mpc.system.processes import NodeGroup, ros_args

CHAIN = {"mode": "realtime", "command_interface": "cmd_vel", "chain.active": "enabled", "wheel_pi.rate_hz": 200.0}


@pytest.mark.parametrize("node, override, name", [
    ("robotino_sim_node.plant_node", {"chain.active": "enabled"}, "command_interface"),  # voltages: refused
    ("robotino_sim_node.plant_node", {**CHAIN, "chain.link.loss": 0.9}, "chain.link.loss"),
    ("robotino_sim_node.plant_node", {**CHAIN, "chain.tick_s": 0.03}, "chain.odometry_rate_hz"),
    ("robotino_geom_mpc.nodes.controller_node", {"chain.active": "enabled", "mode": "lockstep",
                                                 "command_interface": "cmd_vel"}, "chain.active"),
    ("robotino_geom_mpc.nodes.controller_node", {"chain.ramp_rotation_rad_s2": -1.0}, "chain.ramp_rotation_rad_s2"),
])
def test_nodes_refuse_bad_chain_settings_by_name(node, override, name):
    proc = subprocess.run([sys.executable, "-m", node, *ros_args(None, override)], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert name in proc.stderr and "Traceback" not in proc.stderr


def test_identify_over_ros_against_the_chain_plant(tmp_path):
    delay = 0.01
    with NodeGroup(log_dir=tmp_path / "logs") as group:
        plant = group.start("plant_node", ros_args(None, {**CHAIN, "chain.link.delay_s": delay, "duration_s": 40.0}))
        out = tmp_path / "id"
        proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc", "identify", "--ros", "--out", str(out)],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr + plant.stderr_tail(20)
    fit = json.loads((out / "identify.json").read_text())
    # the round trip over DDS adds the node-to-node hops and the plant's 5 ms poll to the WiFi's 2 x 10 ms
    assert 2 * delay - 0.005 <= fit["round_trip_s"] <= 2 * delay + 0.015
    assert fit["ramp_translation_m_s2"] == pytest.approx(0.4, rel=0.1)
    assert fit["ramp_rotation_rad_s2"] == pytest.approx(3.14159, rel=0.1)
    assert fit["speed_loop_time_constant_s"] == pytest.approx(0.025, rel=0.15)  # 200 Hz PI sampling adds ~2.5 ms
