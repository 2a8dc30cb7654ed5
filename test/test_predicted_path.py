"""predicted_path: the MPCs' prediction (eqs. 50-53 under the optimal increments of eq. 56), core and node.

The truth of the core test is independent of `control.mpc`: each axis is integrated in closed form over
each period (pos'' = -d pos' + u, u held), the optimal increments come from a least-squares solve of the
cost on that simulation's superposition. The node test runs the lockstep loop (real processes) and
compares the published paths with the core controller stepped offline as `simulate` steps it, and checks
that nothing is published while no subscription is matched.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Path
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from harness import DEEP_QOS, Harness
from robotino_geom_mpc.bench.dds import lockstep_nodes
from robotino_geom_mpc.control.motion_controller import ControllerInputError, MotionController, state_from_odometry
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.messages import quaternion_to_yaw, stamp_to_ns
from robotino_geom_mpc.system.processes import LOCKSTEP_WAIT_FOR, NodeGroup
from robotino_geom_mpc.scenarios import get_scenario
from robotino_geom_mpc.model.plant import RobotinoPlant

pytestmark = pytest.mark.ros

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _axis_step(pos: float, vel: float, u: float, d: float, T: float) -> tuple[float, float]:
    """pos'' = -d pos' + u over T with u held, in closed form (d > 0)."""
    e = math.exp(-d * T)
    return pos + vel * (1 - e) / d + u * (T / d - (1 - e) / d**2), vel * e + u * (1 - e) / d


def _simulate(x: np.ndarray, u_prev: np.ndarray, delta_U: np.ndarray, dampings, T: float) -> np.ndarray:
    """Positions y(k+1) .. y(k+N) of the three axes under u(k+j) = u(k-1) + sum_{l<=j} Delta u(k+l)."""
    out = np.empty((len(delta_U), 3))
    for a, d in enumerate(dampings):
        pos, vel, u = x[2 * a], x[2 * a + 1], u_prev[a]
        for j, du in enumerate(delta_U[:, a]):
            u += du
            pos, vel = _axis_step(pos, vel, u, d, T)
            out[j, a] = pos
    return out


def test_predicted_outputs_equal_a_step_by_step_simulation_under_the_optimal_increments():
    robot, control = load_params()
    control = replace(control, odometry_filter_time_constant_s=0.0, current_limit_a=0.0)
    controller = MotionController(robot, control)
    with pytest.raises(ControllerInputError):
        controller.predicted_outputs()
    T, N = control.period_s, control.horizon
    dampings = (robot.k_x / robot.M, robot.k_y / robot.M, robot.k_theta / robot.J)
    X = np.array([0.0, 0.3, 0.02, 0.0, 0.25, 0.0])  # on a straight reference at 0.3 m/s
    preview = np.column_stack((0.3 * T * np.arange(1, N + 1), np.full(N, 0.02), np.full(N, 0.25)))
    controller.step(X, preview)
    u_prev = controller.u_prev.copy()  # u(k-1) of the second step
    X2 = X + np.array([0.3 * T + 2e-5, 1e-4, -1e-5, 0.0, 3e-5, 1e-4])  # one period on, a little off
    preview = preview + np.array([0.3 * T, 0.0, 0.0])
    out = controller.step(X2, preview)
    predicted = controller.predicted_outputs()
    # the optimum of J = q |Y_d - Y|^2 + r |Delta U|^2 per axis, Y linear in Delta U (superposition)
    free = _simulate(X2, u_prev, np.zeros((N, 3)), dampings, T)
    delta_U = np.empty((N, 3))
    for a in range(3):
        S = np.column_stack([_simulate(X2, u_prev, np.eye(N)[:, [l]] * (np.arange(3) == a), dampings, T)[:, a]
                             - free[:, a] for l in range(N)])
        q, r = math.sqrt(control.q[a]), math.sqrt(control.r[a])
        lhs = np.vstack((q * S, r * np.eye(N)))
        rhs = np.concatenate((q * (preview[:, a] - free[:, a]), np.zeros(N)))
        delta_U[:, a] = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    assert not out.saturated
    np.testing.assert_allclose(np.array(out.u) - u_prev, delta_U[0], rtol=1e-7, atol=1e-9)  # the applied one
    expected = _simulate(X2, u_prev, delta_U, dampings, T)
    np.testing.assert_allclose(predicted, expected, rtol=0, atol=1e-10)
    assert np.abs(predicted - free).max() > 1e-7  # the increments move the prediction: the test can fail


def _offline_predictions(duration_s: float) -> dict[int, np.ndarray]:
    """The core controller stepped as `simulate` steps it on paper-circle: stamp [ns] -> predicted outputs."""
    robot, control = load_params()
    spec = get_scenario("paper-circle")
    plant = RobotinoPlant(robot)
    controller = MotionController(spec.controller_model(robot), control)
    T, N = control.period_s, control.horizon
    n = int(round(duration_s / T))
    targets = spec.make_reference().position(np.arange(n + N + 1) * T)
    out = {}
    for k in range(n):
        X = state_from_odometry(*plant.odometry())
        voltages = controller.step(X, targets[k + 1: k + N + 1]).voltages
        out[round(k * T * 1e9)] = controller.predicted_outputs()
        plant.step(voltages, T)
    return out


def _path_array(msg: Path) -> np.ndarray:
    return np.array([(p.pose.position.x, p.pose.position.y, quaternion_to_yaw(p.pose.orientation))
                     for p in msg.poses])


def test_node_publishes_the_prediction_only_to_a_subscriber(tmp_path):
    duration_s = 3.0
    _, control = load_params()
    with Harness("path_probe") as h, NodeGroup(log_dir=tmp_path) as group:
        paths: list[Path] = []
        reader = h.node.create_subscription(Path, "predicted_path", paths.append, DEEP_QOS)
        diagnostics = h.collect("diagnostics", DiagnosticArray)
        # paced to real time: unpaced, the loop ran up to 57 ticks ahead of this reader on a loaded host, so the
        # stamp read when the reader left was not the loop's (the last path came 0.57 s after it)
        lockstep_nodes(group, "paper-circle", duration_s,
                       wait_for=[*LOCKSTEP_WAIT_FOR, "predicted_path:1", "diagnostics:1"],
                       plant_overrides={"lockstep_max_realtime_factor": 1.0})
        plant, controller = (next(n for n in group.nodes if n.name == name) for name in ("plant_node",
                                                                                          "controller_node"))
        assert h.spin_until(lambda: diagnostics and stamp_to_ns(diagnostics[-1].header.stamp) > 0.5e9, 240.0), (
            plant.stderr_tail() + controller.stderr_tail())
        h.node.destroy_subscription(reader)  # the path reader leaves mid-run
        left_at = stamp_to_ns(diagnostics[-1].header.stamp)
        assert h.spin_until(lambda: plant.popen.poll() is not None, 240.0), plant.stderr_tail()
        assert plant.popen.returncode == 0
        # the plant has ended; the controller's last diagnostics may still be on their way to this (slower) reader
        final_tick = round((duration_s - control.period_s) * 1e9)
        h.spin_until(lambda: stamp_to_ns(diagnostics[-1].header.stamp) >= final_tick, 60.0)
        last_tick = stamp_to_ns(diagnostics[-1].header.stamp)
        assert last_tick == final_tick
        # a late latched reader gets the last path ever published: stamped about when the first reader left
        late = h.collect("predicted_path", Path, LATCHED)
        h.spin_for(2.0)
    received = {stamp_to_ns(m.header.stamp): m for m in paths}
    assert len(received) > 10
    assert len(late) <= 1
    if late:
        assert stamp_to_ns(late[0].header.stamp) < left_at + 0.5e9 < last_tick
    offline = _offline_predictions(duration_s)
    for stamp, msg in received.items():
        assert msg.header.frame_id == "odom" and len(msg.poses) == control.horizon
        assert [stamp_to_ns(p.header.stamp) for p in msg.poses] == [
            stamp + round(j * control.period_s * 1e9) for j in range(1, control.horizon + 1)]
        np.testing.assert_allclose(_path_array(msg), offline[stamp], rtol=1e-6, atol=1e-9, err_msg=str(stamp))
