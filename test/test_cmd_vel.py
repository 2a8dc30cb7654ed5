"""The cmd_vel path: the controller's twist (model velocity at k+1 in base_link) and the lockstep loop through the
plant's wheel-speed PI loops, against a closed-form axis step and the offline loop of `simulate`."""

import math
import time
from dataclasses import replace

import numpy as np

from probe import ProbeSpinner
from robotino_geom_mpc.core.controller import MotionController
from robotino_geom_mpc.core.params import default_params_file, load_params
from robotino_geom_mpc.ros.processes import NodeGroup, node_arguments
from robotino_geom_mpc.simulation import run_scenario

DURATION_S = 3.0
# the probe's subscriptions; the plant subscribes cmd_vel (no wheel_voltages reader in this loop)
WAIT_FOR = ["odom:1", "/clock:1", "reference_preview:2", "ground_truth/odom:1", "wheel_currents:1", "cmd_vel:1"]


def test_next_velocity_is_the_model_velocity_at_the_next_period_in_base_link():
    robot, control = load_params()
    control = replace(control, odometry_filter_time_constant_s=0.0, current_limit_a=0.0)
    controller = MotionController(robot, control)
    T, N = control.period_s, control.horizon
    X = np.array([0.1, 0.2, -0.05, 0.1, 1.2, 0.4])
    preview = np.column_stack((0.1 + 0.2 * T * np.arange(1, N + 1), -0.05 + 0.1 * T * np.arange(1, N + 1),
                               1.2 + 0.4 * T * np.arange(1, N + 1) + 1e-4))
    out = controller.step(X, preview)
    assert not out.saturated
    expected = []
    for a, d in enumerate((robot.k_x / robot.M, robot.k_y / robot.M, robot.k_theta / robot.J)):
        e = math.exp(-d * T)  # pos'' = -d pos' + u, u held: closed form
        u = out.u[a]
        expected.append((X[2 * a] + X[2 * a + 1] * (1 - e) / d + u * (T / d - (1 - e) / d**2),
                         X[2 * a + 1] * e + u * (1 - e) / d))
    (_, vx), (_, vy), (theta, w) = expected
    c, s = math.cos(theta), math.sin(theta)  # REP-103: v_base_link = R(theta)^T v_odom
    np.testing.assert_allclose(controller.next_velocity(), (c * vx + s * vy, -s * vx + c * vy, w), rtol=1e-12,
                               atol=1e-15)
    assert abs(theta - X[4]) > 1e-3  # the heading moved over the period: the test sees which one is used


def test_lockstep_cmd_vel_loop_equals_simulate_cmd_vel(tmp_path):
    robot, control = load_params()
    probe = ProbeSpinner()
    ticks = round(DURATION_S / control.period_s)
    try:
        with NodeGroup(log_dir=tmp_path) as group:
            for name, argv in node_arguments("paper-circle", default_params_file(), DURATION_S, True,
                                             wait_for=WAIT_FOR, command_interface="cmd_vel").items():
                group.start(name, argv)
            plant = next(n for n in group.nodes if n.name == "plant_node")
            assert group.wait(plant, 240.0), plant.stderr_tail()
            assert plant.popen.returncode == 0
        deadline = time.monotonic() + 60.0  # the probe's thread may lag: let it take every sample
        while min(len(probe.probe.truth), len(probe.probe.currents)) < ticks and time.monotonic() < deadline:
            time.sleep(0.1)
        truth = np.array([probe.probe.truth[s] for s in sorted(probe.probe.truth)])
        currents = np.array(probe.probe.currents)
    finally:
        probe.close()
    offline = run_scenario("paper-circle", robot, control, duration_s=DURATION_S, command_interface="cmd_vel")
    assert len(truth) == len(currents) == offline.n == ticks
    np.testing.assert_allclose(truth, offline.pose, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(currents, offline.currents, rtol=1e-6, atol=1e-9)
    voltage_path = run_scenario("paper-circle", robot, control, duration_s=DURATION_S)
    assert np.abs(offline.pose - voltage_path.pose).max() > 1e-6  # the PI loop changed the run: the test can fail
    assert np.hypot(*(offline.pose[:, :2] - offline.reference[:, :2]).T).max() < 1e-3  # and it closed the loop
