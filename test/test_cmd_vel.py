"""The cmd_vel path: the controller's twist (model velocity at k+1 in base_link) against a closed-form axis step;
`run` records a lockstep cmd_vel run of the nodes (its metrics those of `simulate`, its twists those of the offline
controller tick by tick, read by mcap-ros2-support, and replayed by regress). The loop of the two objects through the
plant's wheel-speed PI loops equals `simulate` tick by tick in-process: test_offline_lockstep.
"""

import json
import math
import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from mcap_ros2.reader import read_ros2_messages

from robotino_geom_mpc.control.motion_controller import MotionController
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.recording.bag_writer import BagWriter
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.recording.report import run_data_from_bag
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.system.processes import RECORDER_WAIT_FOR, node_arguments, recorder_wait_for
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario

pytestmark = pytest.mark.ros

DURATION_S = 3.0


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


def _offline_twists(monkeypatch, robot, control):
    """`simulate`'s cmd_vel run and the twists its controller commanded (every `next_velocity` it returned)."""
    twists = []
    original = MotionController.next_velocity

    def recording(self):
        twists.append(original(self))
        return twists[-1]

    monkeypatch.setattr(MotionController, "next_velocity", recording)
    run = run_scenario(RunConfig("paper-circle", robot, control, duration_s=DURATION_S, command_interface="cmd_vel"))
    monkeypatch.undo()
    return run, np.array(twists)


def test_run_cmd_vel_records_the_metrics_of_simulate_and_the_controllers_twists(tmp_path, monkeypatch):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc", "run", "--scenario", "paper-circle",
                           "--command-interface", "cmd_vel", "--duration", str(DURATION_S), "--out", str(out),
                           "--no-plots"],
                          capture_output=True, text=True, timeout=600, env=os.environ.copy())
    assert proc.returncode == 0, proc.stderr + proc.stdout
    robot, control = load_params()
    offline, twists = _offline_twists(monkeypatch, robot, control)
    ticks = round(DURATION_S / control.period_s)
    assert twists.shape == (ticks, 3)

    metrics = json.loads((out / "metrics.json").read_text())
    want = compute_metrics(offline)
    for key, value in want.items():
        if key.startswith("compute_time") or key in ("realtime_factor", "wall_time_s"):
            continue  # wall-clock measurements
        if isinstance(value, float) and math.isfinite(value):
            assert metrics[key] == pytest.approx(value, rel=1e-6, abs=1e-12), key
        else:
            assert metrics[key] == value, key
    assert metrics["peak_voltage_v"] > 1.0  # the PI loops' voltages were reported (the plant's applied_voltages)

    # an independent reader of the bag: the controller's twists, in publish order, one per tick
    (mcap,) = (out / "bag").glob("*.mcap")
    recorded = np.array([(m.ros_msg.linear.x, m.ros_msg.linear.y, m.ros_msg.angular.z)
                         for m in read_ros2_messages(str(mcap), topics=["/cmd_vel"])])
    np.testing.assert_allclose(recorded, twists, rtol=1e-6, atol=1e-12)
    assert np.abs(twists).max() > 0.1  # the robot moved: a zero twist would not pass

    result = regress_bag(out / "bag")  # the replay of the controller's twists, every tick
    assert result.passed and result.command == "cmd_vel" and result.compared == result.ticks == ticks


def test_the_recorder_waits_for_the_command_of_the_interface():
    # the description publisher's joint_states reader beside the recorder's, for the wheel TF from tick 0
    assert recorder_wait_for() == [w.replace("joint_states:1", "joint_states:2") for w in RECORDER_WAIT_FOR]
    cmd_vel = recorder_wait_for("cmd_vel")
    assert "cmd_vel:2" in cmd_vel and "applied_voltages:1" in cmd_vel
    assert not any("wheel_voltages" in w for w in cmd_vel)
    argv = node_arguments("paper-circle", default_params_file(), 1.0, True, bag="/tmp/b", command_interface="cmd_vel")
    (value,) = [a.split(":=", 1)[1] for a in argv["plant_node"] if a.startswith("lockstep_wait_for:=")]
    assert json.loads(value) == cmd_vel


def test_a_bag_without_any_command_topic_is_refused_by_report_and_regress_by_name(tmp_path):
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    path = tmp_path / "bag"
    with BagWriter(path) as bag:  # the plant's and the trajectory's topics, no controller command
        for name in ("odom", "ground_truth/odom"):
            bag.write(bag.add_topic("/" + name, "nav_msgs/msg/Odometry"), 1, serialize_message(Odometry()), 1)
        bag.add_topic("/wheel_currents", "std_msgs/msg/Float64MultiArray")
        bag.add_topic("/reference_preview", "trajectory_msgs/msg/MultiDOFJointTrajectory")
    with pytest.raises(BagError, match="no 'wheel_voltages' .*applied_voltages"):
        run_data_from_bag(path)
    with pytest.raises(BagError, match="no 'wheel_voltages' .*'cmd_vel'"):
        regress_bag(path)


def test_regress_on_cmd_vel_takes_a_preview_the_node_refuses_as_a_zero_twist(tmp_path):
    """A preview of the wrong length (another horizon) is refused by the node: zero twist, no step. regress
    expects exactly that (one tick, a zero twist matches, a moving one does not), instead of failing.
    """
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Transform, Twist, Vector3
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

    _, control = load_params()
    odom = Odometry()
    odom.pose.pose.orientation.w = 1.0
    preview = MultiDOFJointTrajectory(points=[MultiDOFJointTrajectoryPoint(transforms=[Transform()])
                                              for _ in range(control.horizon + 9)])
    preview.points[0].transforms[0].rotation.w = 1.0
    status = DiagnosticStatus(values=[KeyValue(key="error_x_m", value="0")])
    verdicts = []
    for answer in (0.0, 0.01):
        path = tmp_path / f"bag{answer}"
        with BagWriter(path) as bag:
            for publish, (topic, kind, msg) in enumerate([
                    ("/reference_preview", "trajectory_msgs/msg/MultiDOFJointTrajectory", preview),
                    ("/odom", "nav_msgs/msg/Odometry", odom),
                    ("/cmd_vel", "geometry_msgs/msg/Twist", Twist(linear=Vector3(x=answer))),
                    ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", DiagnosticArray(status=[status]))],
                    start=1):
                bag.write(bag.add_topic(topic, kind), publish, serialize_message(msg), publish)
        result = regress_bag(path)
        assert result.command == "cmd_vel" and result.ticks == result.compared == 1
        verdicts.append((result.passed, result.max_deviation_v))
    assert verdicts == [(True, 0.0), (False, 0.01)]
