"""The trajectory node's ``start_on_enable`` and ``anchor_to_robot`` over DDS, the node alone.

The test is the robot (odometry at a pose it chooses) and the controller (a preview subscription and the latched
``controller_enabled``). The truths: the pose the test sends, and the scenario's reference moved rigidly by
complex numbers (z' = z0 + e^{i theta0} z), independent of `reference.anchor`. The whole loop through the
emulated driver chain: in-process, test_controller_loop_cases (the controller's and the chain's loops, the reference
anchored and started at the enable); over DDS, test_real_robot_page (the real-robot launch on the stand-in driver).
"""

import math
import subprocess
import sys
import time

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from std_msgs.msg import Bool
from trajectory_msgs.msg import MultiDOFJointTrajectory

from harness import DEEP_QOS, Harness
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.messages import quaternion_to_yaw, stamp_to_ns, yaw_to_quaternion
from robotino_geom_mpc.ros.qos import LATCHED_QOS, PUBLISH_QOS
from robotino_geom_mpc.scenarios import SCENARIOS
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

pytestmark = pytest.mark.ros

FIRST, PUSHED = (0.4, -0.2, 0.3), (0.55, -0.35, 2.4)  # where the robot stands, then where it is pushed by hand


def _points(msg: MultiDOFJointTrajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (x, y, yaw), velocities and accelerations of every point of a preview."""
    pos, vel, acc = [], [], []
    for point in msg.points:
        tf, v, a = point.transforms[0], point.velocities[0], point.accelerations[0]
        pos.append((tf.translation.x, tf.translation.y, quaternion_to_yaw(tf.rotation)))
        vel.append((v.linear.x, v.linear.y, v.angular.z))
        acc.append((a.linear.x, a.linear.y, a.angular.z))
    return np.array(pos), np.array(vel), np.array(acc)


def _moved(rows: np.ndarray, pose, translate: bool) -> np.ndarray:
    """(x, y, theta) rows (or their derivatives: no translation, no heading added) moved rigidly onto `pose`."""
    x0, y0, theta0 = pose
    z = np.exp(1j * theta0) * (rows[:, 0] + 1j * rows[:, 1]) + ((x0 + 1j * y0) if translate else 0.0)
    return np.column_stack((z.real, z.imag, rows[:, 2] + (theta0 if translate else 0.0)))


def _wrapped(angles: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(angles)))


class _Robot:
    """The test as the robot (odometry at `pose` every 20 ms) and the controller (controller_enabled)."""

    def __init__(self, h: Harness, ns: str) -> None:
        self.pose, self.clock = FIRST, h.node.get_clock()
        self.odom = h.node.create_publisher(Odometry, f"{ns}/odom", PUBLISH_QOS)
        self.enabled = h.node.create_publisher(Bool, f"{ns}/controller_enabled", LATCHED_QOS)
        self.previews: list[tuple[float, MultiDOFJointTrajectory]] = []
        h.node.create_subscription(MultiDOFJointTrajectory, f"{ns}/reference_preview",
                                   lambda m: self.previews.append((time.time(), m)), DEEP_QOS)
        self.paths = h.collect(f"{ns}/reference_path", Path, LATCHED_QOS)
        h.node.create_timer(0.02, self._send)

    def _send(self) -> None:
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.header.stamp = self.clock.now().to_msg()
        msg.pose.pose.position.x, msg.pose.pose.position.y = self.pose[:2]
        msg.pose.pose.orientation = yaw_to_quaternion(self.pose[2])
        self.odom.publish(msg)

    def holds(self, since: float) -> list[np.ndarray]:
        """The positions of the previews received since `since`, each checked to be a hold (every point the same,
        at rest).
        """
        out = []
        for at, msg in self.previews:
            if at >= since:
                pos, vel, acc = _points(msg)
                assert np.abs(pos - pos[0]).max() < 1e-12 and not vel.any() and not acc.any()
                out.append(pos[0])
        return out


def _start_node(group: NodeGroup, ns: str, scenario: str):
    return group.start("trajectory_node", ros_args(None, {
        "mode": "realtime", "scenario": scenario, "start_on_enable": True, "anchor_to_robot": True,
        "start_settle_s": 0.3}) + ["-r", f"__ns:={ns}"])


def test_the_reference_holds_at_the_robot_until_the_enable_then_starts_there_and_holds_again_at_a_disable(tmp_path):
    _, control = load_params()
    Ts, N = control.period_s, control.horizon
    circle = SCENARIOS["paper-circle"].make_reference()
    with NodeGroup(log_dir=tmp_path) as group, Harness("start_on_enable_test") as h:
        robot = _Robot(h, "/soe")
        node = _start_node(group, "/soe", "paper-circle")
        assert h.spin_until(lambda: len(robot.previews) >= 20, 60.0), node.stderr_tail()
        held = robot.holds(0.0)
        np.testing.assert_allclose(held, [FIRST] * len(held), atol=1e-12)  # the robot's pose, at rest
        assert robot.paths == []  # the path comes with the start
        robot.enabled.publish(Bool(data=False))  # (disabled: no start)
        robot.pose = PUSHED
        h.spin_for(0.5)
        pushed_at = time.time()
        h.spin_for(0.5)
        np.testing.assert_allclose(_wrapped(np.array(robot.holds(pushed_at))[:, 2]), PUSHED[2], atol=1e-12)
        np.testing.assert_allclose(np.array(robot.holds(pushed_at))[:, :2], [PUSHED[:2]] * len(robot.holds(pushed_at)),
                                   atol=1e-12)
        enabled_at = time.time()
        robot.enabled.publish(Bool(data=True))
        assert h.spin_until(lambda: len(robot.paths) == 1, 30.0), node.stderr_tail()
        h.spin_for(3.0)
        disabled_at = time.time()
        robot.enabled.publish(Bool(data=False))
        h.spin_for(1.0)
        reenabled_at = time.time()
        robot.enabled.publish(Bool(data=True))
        assert h.spin_until(lambda: len(robot.paths) == 2, 30.0), node.stderr_tail()
        h.spin_for(0.3)
        log = node.stdout_path.read_text() + node.stderr_path.read_text()
    # t = 0: the path's stamp (its first pose, the reference at t = 0); the preview stamped there is the first that
    # moves: every one before is a hold, and it came after the enable was sent
    t0 = stamp_to_ns(robot.paths[0].header.stamp)
    assert stamp_to_ns(robot.paths[0].poses[0].header.stamp) == t0
    print(f"t = 0 of the reference {(t0 * 1e-9 - enabled_at) * 1e3:.1f} ms after the enable was published")
    assert enabled_at <= t0 * 1e-9
    stamps = [stamp_to_ns(m.header.stamp) for _, m in robot.previews]
    started = [(s, m) for s, (at, m) in zip(stamps, robot.previews) if t0 <= s and at < disabled_at]
    assert started[0][0] == t0 and len(started) > 2.5 / Ts
    assert all(s < t0 for s, (at, _) in zip(stamps, robot.previews) if at < enabled_at)
    # the previews from t = 0 on are paper-circle moved onto the pushed pose, at the time since t = 0
    for stamp, msg in started:
        pos, vel, acc = _points(msg)
        t = (stamp - t0) * 1e-9 + Ts * np.arange(N + 1)
        expected = [np.asarray(x) for x in circle.sample(t)]
        np.testing.assert_allclose(pos[:, :2], _moved(expected[0], PUSHED, True)[:, :2], atol=1e-9)
        np.testing.assert_allclose(_wrapped(pos[:, 2] - PUSHED[2]), 0.0, atol=1e-9)  # theta_d = 0, turned
        np.testing.assert_allclose(vel, _moved(expected[1], PUSHED, False), atol=1e-9)
        np.testing.assert_allclose(acc, _moved(expected[2], PUSHED, False), atol=1e-9)
    np.testing.assert_allclose(_points(started[0][1])[0][0, :2], PUSHED[:2], atol=1e-12)  # t = 0: the robot's pose
    path = np.array([(p.pose.position.x, p.pose.position.y) for p in robot.paths[0].poses])
    centre = np.array(PUSHED[:2]) + 0.5 * np.array([-math.sin(PUSHED[2]), math.cos(PUSHED[2])])
    np.testing.assert_allclose(np.hypot(*(path - centre).T), 0.5, atol=1e-9)
    # the disable: holds again (at the robot's pose, which stayed), and the next enable starts anew
    between = [m for s, (at, m) in zip(stamps, robot.previews) if disabled_at + 0.2 < at < reenabled_at]
    assert between and all(np.abs(_points(m)[1]).max() == 0.0 for m in between)
    np.testing.assert_allclose(_points(between[-1])[0][0, :2], PUSHED[:2], atol=1e-12)
    assert stamp_to_ns(robot.paths[1].header.stamp) * 1e-9 >= reenabled_at
    assert "the controller is disabled: the reference holds its start again" in log


def test_goals_anchored_hold_the_robots_pose_and_take_goals_from_the_start_on(tmp_path):
    goal = (0.9, 0.2, -0.5)
    with NodeGroup(log_dir=tmp_path) as group, Harness("start_on_enable_goals") as h:
        robot = _Robot(h, "/soeg")
        goals = h.node.create_publisher(PoseStamped, "/soeg/goal_pose", 10)
        node = _start_node(group, "/soeg", "goals")
        assert h.spin_until(lambda: len(robot.previews) >= 10, 60.0), node.stderr_tail()
        assert goals.get_subscription_count() == 0  # holding: no goal is taken before the start pose is known
        robot.enabled.publish(Bool(data=True))
        assert h.spin_until(lambda: robot.paths and goals.get_subscription_count() == 1, 30.0), node.stderr_tail()
        enabled_at = time.time()
        h.spin_for(0.3)
        np.testing.assert_allclose(robot.holds(enabled_at)[-1], FIRST, atol=1e-12)  # goals: holds the robot's pose
        msg = PoseStamped()
        msg.header.frame_id = "odom"
        msg.pose.position.x, msg.pose.position.y = goal[:2]
        msg.pose.orientation = yaw_to_quaternion(goal[2])
        goals.publish(msg)
        assert h.spin_until(lambda: len(robot.paths) >= 2, 30.0), node.stderr_tail()
    last = robot.paths[-1].poses[-1].pose
    np.testing.assert_allclose([last.position.x, last.position.y, quaternion_to_yaw(last.orientation)], goal,
                               atol=1e-9)  # the goal where it was sent, in odom (not moved by the anchor)
    first = robot.paths[-1].poses[0].pose
    np.testing.assert_allclose([first.position.x, first.position.y], FIRST[:2], atol=1e-6)  # from the robot's pose


@pytest.mark.parametrize("override, names", [
    ({"start_on_enable": True}, "start_on_enable is a realtime feature"),
    ({"anchor_to_robot": True, "start_on_enable": True}, "start_on_enable and anchor_to_robot are realtime features"),
])
def test_lockstep_refuses_the_realtime_start_features(override, names):
    proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc.nodes.trajectory_node",
                           *ros_args(None, {"mode": "lockstep", **override})], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2
    assert names in proc.stderr and "in lockstep the plant's /clock drives the reference" in proc.stderr
    assert "Traceback" not in proc.stderr
