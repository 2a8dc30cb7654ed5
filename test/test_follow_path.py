"""Nav2's follow_path action over DDS: the real plant, controller and trajectory nodes, an rclpy action client.

The client does what nav2_simple_commander's ``BasicNavigator.followPath(path, controller_id, goal_checker_id)``
does (a nav2_msgs/action/FollowPath goal on ``follow_path``, feedback, ``getResult``); BasicNavigator itself is
navigation2's code, which this repository does not carry. The loop runs in lockstep, paced to a few times real
time (see test_goals_node for why lockstep), so the goals' timing (replans at 1 Hz) is the simulated clock's.

Truths: the plant's ground truth (``ground_truth/odom``) against the path's end (in ``map`` through the
transform the test publishes), the nominal current 0.86 A, Nav2's error codes (nav2_msgs' own constants), and for
a cancel the distance an analytic stop from the cruise speed takes under the limits (below).
"""

from __future__ import annotations

import math
from pathlib import Path as FilePath

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, TransformStamped
from nav2_msgs.action import FollowPath
from nav_msgs.msg import Odometry, Path
from rclpy.action import ActionClient
from std_msgs.msg import Float64MultiArray
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import MultiDOFJointTrajectory

from harness import Harness
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.reference.goal_file import LIMIT_DEFAULTS
from robotino_geom_mpc.ros.messages import quaternion_to_yaw, stamp_to_ns, yaw_to_quaternion
from robotino_geom_mpc.ros.tf_listener import TF_QOS
from robotino_geom_mpc.system.processes import NodeGroup, node_arguments

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NOMINAL_CURRENT_A = 0.86
PACE = 3.0  # simulated seconds per wall second
STATUS = {4: "SUCCEEDED", 5: "CANCELED", 6: "ABORTED"}  # action_msgs/GoalStatus


def _pose(x: float, y: float, yaw: float, frame: str) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y = float(x), float(y)
    msg.pose.orientation = yaw_to_quaternion(yaw)
    return msg


def _path(poses: np.ndarray, frame: str = "odom") -> Path:
    """A planner's path: poses without stamps, each in the path's frame."""
    msg = Path()
    msg.header.frame_id = frame
    msg.poses = [_pose(*p, frame=frame) for p in poses]
    return msg


def _line(start: np.ndarray, end: np.ndarray, step: float = 0.05) -> np.ndarray:
    """Poses every `step` from `start` to `end` (x, y), heading along the line."""
    n = max(1, int(math.ceil(np.hypot(*(end - start)) / step)))
    xy = start + np.linspace(0.0, 1.0, n + 1)[:, None] * (end - start)
    return np.column_stack((xy, np.full(n + 1, math.atan2(*(end - start)[::-1]))))


def _corner_path(origin: np.ndarray, heading: float) -> np.ndarray:
    """3 m: 1.5 m along `heading`, a 90 degree left corner, 1.5 m; poses 5 cm apart heading along the path."""
    a = origin + 1.5 * np.array([math.cos(heading), math.sin(heading)])
    b = a + 1.5 * np.array([-math.sin(heading), math.cos(heading)])
    return np.vstack((_line(origin, a), _line(a, b)[1:]))


class FollowPathRun:
    """The running loop, the client and the test's view of them."""

    def __init__(self, h: Harness, group: NodeGroup) -> None:
        self.h, self.group = h, group
        self.truth = h.collect("ground_truth/odom", Odometry)
        self.currents = h.collect("wheel_currents", Float64MultiArray)
        self.voltages = h.collect("wheel_voltages", Float64MultiArray)
        self.previews = h.collect("reference_preview", MultiDOFJointTrajectory)
        self.client = ActionClient(h.node, FollowPath, "follow_path")
        self.tf_pub = h.node.create_publisher(TFMessage, "/tf", TF_QOS)
        self.map_to_odom: tuple[float, float, float] | None = None
        h.node.create_timer(0.05, self._publish_tf)  # AMCL's map -> odom, at 20 Hz of wall time
        self.feedback: list[tuple[float, float]] = []  # (distance_to_goal, speed)

    def _publish_tf(self) -> None:
        if self.map_to_odom is None:
            return
        x, y, yaw = self.map_to_odom
        tf = TransformStamped()
        tf.header.frame_id, tf.child_frame_id = "map", "odom"
        tf.header.stamp = self.h.node.get_clock().now().to_msg()
        tf.transform.translation.x, tf.transform.translation.y = x, y
        tf.transform.rotation = yaw_to_quaternion(yaw)
        self.tf_pub.publish(TFMessage(transforms=[tf]))

    def now_ns(self) -> int:
        return stamp_to_ns(self.truth[-1].header.stamp)

    def truth_pose(self) -> np.ndarray:
        p = self.truth[-1].pose.pose
        return np.array([p.position.x, p.position.y, quaternion_to_yaw(p.orientation)])

    def send(self, path: Path, controller_id: str = "", goal_checker_id: str = ""):
        """The goal handle of an accepted goal (asserted), as BasicNavigator.followPath sends it."""
        goal = FollowPath.Goal(path=path, controller_id=controller_id, goal_checker_id=goal_checker_id)
        future = self.client.send_goal_async(goal, feedback_callback=self._on_feedback)
        assert self.h.spin_until(future.done, 10.0), "no answer to the goal"
        handle = future.result()
        assert handle.accepted
        return handle

    def _on_feedback(self, msg) -> None:
        fb = msg.feedback
        self.feedback.append((fb.distance_to_goal, fb.speed))

    def result(self, handle, timeout_s: float = 60.0) -> tuple[str, int, str]:
        future = handle.get_result_async()
        assert self.h.spin_until(future.done, timeout_s), "no result"
        res = future.result()
        return STATUS.get(res.status, str(res.status)), res.result.error_code, res.result.error_msg

    def spin_sim(self, seconds: float) -> None:
        """Spin until the ground truth has advanced `seconds` of simulated time."""
        end = self.now_ns() + int(seconds * 1e9)
        assert self.h.spin_until(lambda: self.now_ns() >= end, seconds / PACE * 3 + 10.0)

    def rest_pose(self) -> np.ndarray:
        """The ground truth once it shows the robot at rest (the harness may read it a little behind the loop)."""
        def resting() -> bool:
            twist = self.truth[-1].twist.twist
            return max(abs(twist.linear.x), abs(twist.linear.y), abs(twist.angular.z)) < 1e-4
        assert self.h.spin_until(resting, 20.0), "the robot did not come to rest"
        return self.truth_pose()

    def log(self) -> str:
        node = next(n for n in self.group.nodes if n.name == "trajectory_node")
        return FilePath(node.stderr_path).read_text() + FilePath(node.stdout_path).read_text()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    args = node_arguments("goals", default_params_file(), 1000.0, lockstep=True,
                          overrides={"plant_node": {"lockstep_max_realtime_factor": PACE},
                                     "trajectory_node": {"follow_path.xy_goal_tolerance": 0.01,
                                                         "follow_path.yaw_goal_tolerance": math.radians(1.0)}})
    with NodeGroup(log_dir=tmp_path_factory.mktemp("follow_path")) as group, Harness("follow_path_test") as h:
        r = FollowPathRun(h, group)
        for name in ("plant_node", "controller_node", "trajectory_node"):
            group.start(name, args[name])
        assert h.spin_until(lambda: len(r.truth) > 0, 60.0), "the loop did not start"
        assert h.spin_until(r.client.server_is_ready, 20.0), "no follow_path action server"
        yield r


def _peak_current(run: FollowPathRun, since: int) -> float:
    return max(np.abs(m.data).max() for m in run.currents[since:])


def test_bad_goals_get_their_error_code_and_the_robot_holds(run):
    before = run.rest_pose()
    nan_path = _path(_line(np.zeros(2), np.array([1.0, 0.0])))
    nan_path.poses[3].pose.position.y = math.nan
    cases = [(_path(np.zeros((0, 3))), "", FollowPath.Result.INVALID_PATH),
             (nan_path, "", FollowPath.Result.INVALID_PATH),
             (_path(_line(np.zeros(2), np.array([1.0, 0.0])), frame="nowhere"), "", FollowPath.Result.TF_ERROR),
             (_path(_line(np.zeros(2), np.array([1.0, 0.0]))), "DWB", FollowPath.Result.INVALID_CONTROLLER)]
    for path, controller_id, code in cases:
        status, error, message = run.result(run.send(path, controller_id))
        assert (status, error) == ("ABORTED", code), message
    run.spin_sim(0.5)
    assert np.abs(run.truth_pose() - before).max() <= 1e-6  # held where it stood


def test_a_3m_path_with_a_corner_succeeds_within_1cm_and_1deg(run):
    start_pose, since = run.rest_pose(), len(run.currents)
    path = _corner_path(start_pose[:2], 0.0)
    handle = run.send(_path(path), "FollowPath", "goal_checker")
    first_feedback = len(run.feedback)
    status, error, message = run.result(handle)
    assert (status, error) == ("SUCCEEDED", FollowPath.Result.NONE), message
    end = run.rest_pose()
    position_error = float(np.hypot(*(end[:2] - path[-1, :2])))
    yaw_error = abs(math.remainder(end[2] - path[-1, 2], math.tau))
    peak = _peak_current(run, since)
    feedback = run.feedback[first_feedback:]
    print(f"corner path: error {position_error * 1e3:.2f} mm, {math.degrees(yaw_error):.3f} deg, peak current "
          f"{peak:.3f} A, {len(feedback)} feedbacks")
    assert position_error <= 0.01 and yaw_error <= math.radians(1.0)
    assert peak <= NOMINAL_CURRENT_A
    # feedback streamed through the goal, its distance shrinking to the end (its 20 Hz grid of reference time is
    # test_path_follower's: the harness reads the simulated time too unevenly to time it here)
    assert len(feedback) > 100
    assert feedback[0][0] > 2.5 and feedback[-1][0] < 0.1


def test_cancel_brakes_to_rest_within_the_limits_braking_distance(run):
    start = run.rest_pose()
    path = _line(start[:2], start[:2] + np.array([3.0, 0.0]))
    path[:, 2] = start[2]  # keep the heading: a straight run along +x
    handle = run.send(_path(path))
    # into the cruise: the reference's speed steady (two feedbacks alike)
    assert run.h.spin_until(lambda: len(run.feedback) > 2 and run.feedback[-1][1] > 0.2 and
                            abs(run.feedback[-1][1] - run.feedback[-2][1]) < 1e-6, 30.0)
    sent_ns = run.now_ns()
    cancel = handle.cancel_goal_async()
    assert run.h.spin_until(cancel.done, 10.0)
    status, _, message = run.result(handle)
    assert status == "CANCELED", message
    rest = run.rest_pose()
    # the stop starts at the first tick after the cancel whose reference decelerates
    braking = next(m for m in run.previews if stamp_to_ns(m.header.stamp) > sent_ns
                   and m.points[0].accelerations[0].linear.x < -1e-9)
    stamp = stamp_to_ns(braking.header.stamp)
    speed = braking.points[0].velocities[0].linear.x
    at_cancel = next(m for m in run.truth if stamp_to_ns(m.header.stamp) == stamp).pose.pose.position
    # Independent truth: a stop v0 (1 - q(t / T)), q the quintic smoothstep, under |a| <= a_max and |j| <= j_max
    # needs T >= 15 v0 / (8 a_max) (q' peaks at 15/8) and T >= sqrt(v0 10 / sqrt(3) / j_max) (q'' at 10/sqrt(3)),
    # and travels v0 T / 2; the planner keeps 0.998 of each limit and finds T to 0.2 %.
    a_max, j_max = LIMIT_DEFAULTS["goals.max_acceleration_mps2"], LIMIT_DEFAULTS["goals.max_jerk_mps3"]
    T = max(15.0 * speed / (8.0 * a_max), math.sqrt(speed * 10.0 / math.sqrt(3.0) / j_max)) / 0.998 * 1.002
    travelled = float(np.hypot(rest[0] - at_cancel.x, rest[1] - at_cancel.y))
    print(f"cancel at {speed:.3f} m/s: travelled {travelled * 1e3:.1f} mm, bound {speed * T / 2 * 1e3:.1f} mm")
    assert travelled <= speed * T / 2 + 0.002  # (+ the tracking error)


def _to_map(map_to_odom: tuple[float, float, float], pose: np.ndarray) -> np.ndarray:
    """A pose (x, y, yaw) in odom, in map: p_map = R(psi) p_odom + t for the map -> odom transform (t, psi)."""
    x, y, psi = map_to_odom
    c, s = math.cos(psi), math.sin(psi)
    return np.array([c * pose[0] - s * pose[1] + x, s * pose[0] + c * pose[1] + y, pose[2] + psi])


def test_replanning_at_1hz_takes_over_without_a_voltage_step_and_succeeds(run):
    rng = np.random.default_rng(7)
    start = run.rest_pose()
    goal = start[:2] + np.array([2.0, 1.5])  # 2.5 m: the replans come while it moves
    heading = math.atan2(1.5, 2.0)
    handles, replans, since = [], [], len(run.currents)
    first = len(run.voltages)
    for k in range(6):  # a new path from the current pose every second, its end moved by up to 5 cm
        here = run.truth_pose()
        end = goal + rng.uniform(-0.035, 0.035, 2)
        path = _line(here[:2], end)
        path[:, 2] = heading  # the goal's heading (not the direction from here to a nearby end)
        replans.append(len(run.voltages))
        handles.append(run.send(_path(path)))
        run.spin_sim(1.0)
    status, error, message = run.result(handles[-1])
    assert (status, error) == ("SUCCEEDED", FollowPath.Result.NONE), message
    for handle in handles[:-1]:  # each preempted by the next, as Nav2's server ends them
        assert run.result(handle)[:2] == ("ABORTED", FollowPath.Result.NONE)
    position_error = float(np.hypot(*(run.rest_pose()[:2] - end)))
    peak = _peak_current(run, since)
    # the voltage steps at the replans no larger than those the limited motion makes elsewhere in the run
    u = np.array([m.data for m in run.voltages[first:]])
    steps = np.abs(np.diff(u, axis=0)).max(axis=1)
    near = np.zeros(len(steps), dtype=bool)
    for index in replans[1:]:
        near[max(0, index - first - 10): index - first + 10] = True
    print(f"replans: error {position_error * 1e3:.2f} mm, peak current {peak:.3f} A, largest voltage step "
          f"{steps[near].max():.4f} V at the replans, {steps[~near].max():.4f} V elsewhere")
    assert position_error <= 0.01 and peak <= NOMINAL_CURRENT_A
    assert steps[near].max() <= 1.5 * steps[~near].max()


def test_a_path_in_map_follows_a_moving_map_to_odom(run):
    run.map_to_odom = (0.5, 0.3, math.radians(30.0))
    run.h.spin_for(0.5)  # the transform reaches the trajectory node
    since = len(run.currents)
    path = _corner_path(_to_map(run.map_to_odom, run.rest_pose())[:2], 0.4)
    handle = run.send(_path(path, frame="map"))
    run.spin_sim(5.0)
    run.map_to_odom = (0.52, 0.3, math.radians(30.0))  # a localization correction of 2 cm
    status, error, message = run.result(handle)
    assert (status, error) == ("SUCCEEDED", FollowPath.Result.NONE), message
    end = _to_map(run.map_to_odom, run.rest_pose())
    position_error = float(np.hypot(*(end[:2] - path[-1, :2])))
    yaw_error = abs(math.remainder(end[2] - path[-1, 2], math.tau))
    peak = _peak_current(run, since)
    print(f"map path: error in map {position_error * 1e3:.2f} mm, {math.degrees(yaw_error):.3f} deg, peak "
          f"current {peak:.3f} A")
    assert position_error <= 0.01 and yaw_error <= math.radians(1.0) and peak <= NOMINAL_CURRENT_A
    run.map_to_odom = None
