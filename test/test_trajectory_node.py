"""The trajectory node alone over DDS: /clock in, previews and the latched reference path out."""

import subprocess
import sys
import time

import numpy as np
import pytest
from nav_msgs.msg import Odometry, Path
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.ros.messages import ns_to_stamp, quaternion_to_yaw, stamp_to_ns
from robotino_geom_mpc.ros.qos import LATCHED_QOS, PUBLISH_QOS
from harness import DEEP_QOS, Harness
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

pytestmark = pytest.mark.ros

NODE = "robotino_trajectory"
WAYPOINTS = [0.3, 0.1, 0.0, 0.3, 0.1, 1.0]


def positions(msg):
    out = []
    for point in msg.points:
        tf = point.transforms[0]
        out.append((tf.translation.x, tf.translation.y, quaternion_to_yaw(tf.rotation)))
    return np.array(out)


@pytest.fixture(scope="module")
def trajectory(tmp_path_factory):
    with NodeGroup(log_dir=tmp_path_factory.mktemp("trajectory")) as group, Harness("trajectory_test") as h:
        h.previews = h.collect("reference_preview", MultiDOFJointTrajectory)
        h.clock_pub = h.node.create_publisher(Clock, "/clock", PUBLISH_QOS)
        node = group.start("trajectory_node", ros_args(None, {
            "mode": "lockstep", "scenario": "point-to-point", "waypoints": WAYPOINTS}))
        assert h.spin_until(lambda: h.clock_pub.get_subscription_count() >= 1
                            and h.node.count_publishers("reference_preview") >= 1, 30.0), node.stderr_tail()
        h.spin_for(0.2)
        yield h


def test_previews_follow_the_clock_one_tick_ahead(trajectory):
    h = trajectory
    _, control = load_params()
    Ts, N = control.period_s, control.horizon
    Ts_ns = round(Ts * 1e9)
    reference = make_reference("point-to-point", waypoints=np.reshape(WAYPOINTS, (-1, 3)))
    ticks = [150, 151, 152]
    for k in ticks:
        h.clock_pub.publish(Clock(clock=ns_to_stamp(k * Ts_ns)))
        h.spin_for(0.05)
    assert h.spin_until(lambda: len({stamp_to_ns(m.header.stamp) for m in h.previews}) >= 4)
    h.spin_for(0.2)
    # a subscription whose writer-side match comes after a clock gets that tick's previews again (the same ones)
    first = {}
    for msg in h.previews:
        first.setdefault(stamp_to_ns(msg.header.stamp), msg)
        assert msg == first[stamp_to_ns(msg.header.stamp)]
    stamps = list(first)
    assert stamps == [k * Ts_ns for k in (150, 151, 152, 153)]  # the first clock also gives its own tick
    for msg, stamp in zip(first.values(), stamps):
        assert msg.header.frame_id == "odom" and list(msg.joint_names) == ["base_link"]
        assert len(msg.points) == N + 1
        assert [stamp_to_ns(p.time_from_start) for p in msg.points] == [j * Ts_ns for j in range(N + 1)]
        t = stamp * 1e-9 + Ts * np.arange(N + 1)
        pos, vel, acc, _ = reference.sample(t)
        assert np.allclose(positions(msg), pos, rtol=0, atol=1e-12)
        v = np.array([(p.velocities[0].linear.x, p.velocities[0].linear.y, p.velocities[0].angular.z)
                      for p in msg.points])
        a = np.array([(p.accelerations[0].linear.x, p.accelerations[0].linear.y, p.accelerations[0].angular.z)
                      for p in msg.points])
        assert np.allclose(v, vel, rtol=0, atol=1e-12) and np.allclose(a, acc, rtol=0, atol=1e-12)
    assert np.ptp(positions(h.previews[-1])[:, 0]) > 0  # the first move is under way: the points differ


def test_a_repeated_clock_repeats_both_previews(trajectory):
    h = trajectory
    Ts_ns = round(load_params()[1].period_s * 1e9)
    before = len(h.previews)
    h.clock_pub.publish(Clock(clock=ns_to_stamp(152 * Ts_ns)))
    assert h.spin_until(lambda: len(h.previews) >= before + 2)
    assert [stamp_to_ns(m.header.stamp) for m in h.previews[before:]] == [152 * Ts_ns, 153 * Ts_ns]


def test_the_previews_of_ticks_whose_clock_was_dropped_are_sent(trajectory):
    """Over a link the lockstep plant runs at once through ticks with no answer due; a /clock the node's reader
    dropped in such a burst must not leave a tick without its preview: a late odometry of that stamp would wait.
    """
    h = trajectory
    Ts_ns = round(load_params()[1].period_s * 1e9)
    h.clock_pub.publish(Clock(clock=ns_to_stamp(170 * Ts_ns)))
    assert h.spin_until(lambda: any(stamp_to_ns(m.header.stamp) == 171 * Ts_ns for m in h.previews))
    h.spin_for(0.2)
    before = len(h.previews)
    h.clock_pub.publish(Clock(clock=ns_to_stamp(173 * Ts_ns)))  # the clocks of ticks 171 and 172 lost
    assert h.spin_until(lambda: len(h.previews) >= before + 3)
    h.spin_for(0.2)
    assert [stamp_to_ns(m.header.stamp) for m in h.previews[before:]] == [k * Ts_ns for k in (172, 173, 174)]


def test_a_late_subscription_gets_the_current_previews_at_once(trajectory):
    """A controller whose endpoints match after the clock of a tick gets that tick's previews, no clock needed."""
    h = trajectory
    Ts_ns = round(load_params()[1].period_s * 1e9)
    h.clock_pub.publish(Clock(clock=ns_to_stamp(160 * Ts_ns)))
    before = len(h.previews)
    assert h.spin_until(lambda: len(h.previews) >= before + 1)  # the clock has been handled
    h.spin_for(0.2)
    late = h.collect("reference_preview", MultiDOFJointTrajectory)
    assert h.spin_until(lambda: len(late) >= 2), "no preview for a subscription that matched after the clock"
    h.spin_for(0.2)
    assert [stamp_to_ns(m.header.stamp) for m in late] == [160 * Ts_ns, 161 * Ts_ns]


def test_reference_path_is_latched_for_a_late_subscriber(trajectory):
    h = trajectory
    _, control = load_params()
    (info,) = h.node.get_publishers_info_by_topic("/reference_path")
    assert info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    paths = h.collect("reference_path", Path, LATCHED_QOS)  # subscribes long after the publication
    assert h.spin_until(lambda: len(paths) == 1)
    reference = make_reference("point-to-point", waypoints=np.reshape(WAYPOINTS, (-1, 3)))
    t = np.array([stamp_to_ns(p.header.stamp) * 1e-9 for p in paths[0].poses])
    assert t[0] == 0.0 and t[-1] == pytest.approx(reference.duration_s, abs=control.period_s / 2)
    got = np.array([(p.pose.position.x, p.pose.position.y, quaternion_to_yaw(p.pose.orientation))
                    for p in paths[0].poses])
    assert np.allclose(got, reference.position(t), rtol=0, atol=1e-9)
    assert paths[0].header.frame_id == "odom"
    volatile = h.collect("reference_path", Path, QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    h.spin_for(0.5)
    assert volatile == []  # published once, not streamed


@pytest.mark.parametrize("every", [1, 5])
def test_realtime_reference_starts_the_settle_time_after_a_controller_and_odometry_are_there(tmp_path, every):
    """No preview without an odom publisher, none for ``start_settle_s`` after; then point 0 follows the reference,
    a preview every ``preview_every`` periods with N + ``preview_every`` points, each the reference at its time.
    """
    settle_s = 1.0
    _, control = load_params()
    reference = make_reference("paper-circle")
    arrivals = []
    with NodeGroup(log_dir=tmp_path) as group, Harness("trajectory_realtime_test") as h:
        # a namespace of its own: the module's lockstep node publishes reference_preview too
        sub = h.node.create_subscription(MultiDOFJointTrajectory, "/realtime/reference_preview",
                                         lambda msg: arrivals.append((time.monotonic(), msg)), DEEP_QOS)
        node = group.start("trajectory_node", ros_args(None, {
            "mode": "realtime", "scenario": "paper-circle", "start_settle_s": settle_s, "preview_every": every})
            + ["-r", "__ns:=/realtime"])
        assert h.spin_until(lambda: sub.get_publisher_count() >= 1, 30.0), node.stderr_tail()
        h.spin_for(settle_s + 0.5)
        assert arrivals == []  # a controller listens, but no robot sends odometry
        h.node.create_publisher(Odometry, "/realtime/odom", PUBLISH_QOS)
        odometry_at = time.monotonic()
        assert h.spin_until(lambda: len(arrivals) >= 50 // every, 10.0), node.stderr_tail()
    # the node sees the odom publisher a little after it exists; without the settle the first preview
    # would follow within a control period or two
    assert arrivals[0][0] - odometry_at > settle_s - 0.2
    stamps = np.array([stamp_to_ns(msg.header.stamp) for _, msg in arrivals])
    assert np.all(np.diff(stamps) > 0)
    assert np.median(np.diff(stamps)) == pytest.approx(every * control.period_s * 1e9, rel=0.2)  # one per `every`
    t = (stamps - stamps[0]) * 1e-9  # the reference's time: t = 0 at the first preview
    points = np.arange(control.horizon + every) * control.period_s
    assert {len(msg.points) for _, msg in arrivals} == {control.horizon + every}
    for (_, msg), t_k in zip(arrivals, t):
        np.testing.assert_allclose(positions(msg), reference.position(t_k + points), atol=1e-12)
    assert np.all(positions(arrivals[0][1])[0] == 0.0)  # paper-circle starts at rest at the origin


def test_parameter_set_is_validated(trajectory):
    h = trajectory
    (bad,) = h.set_parameters(NODE, {"scenario": "spiral"})
    assert not bad.successful and "scenario" in bad.reason
    (bad_wp,) = h.set_parameters(NODE, {"waypoints": [1.0, 2.0]})
    assert not bad_wp.successful and "waypoints" in bad_wp.reason
    (bad_period,) = h.set_parameters(NODE, {"control.period_s": -0.01})
    assert not bad_period.successful and "control.period_s" in bad_period.reason
    (bad_settle,) = h.set_parameters(NODE, {"start_settle_s": -1.0})
    assert not bad_settle.successful and "start_settle_s" in bad_settle.reason
    assert h.get_parameters(NODE, ["scenario", "waypoints", "control.period_s"]) == [
        "point-to-point", WAYPOINTS, load_params()[1].period_s]


def test_period_and_horizon_cannot_change_while_the_node_runs(trajectory):
    """Valid values, refused because the node's timer, preview layout and grid are built on them."""
    h = trajectory
    _, control = load_params()
    for name, value in (("control.period_s", 2 * control.period_s), ("control.horizon", control.horizon + 1)):
        (result,) = h.set_parameters(NODE, {name: value})
        assert not result.successful and name in result.reason and "cannot change while the node runs" in result.reason
    assert h.get_parameters(NODE, ["control.period_s", "control.horizon"]) == [control.period_s, control.horizon]
    (allowed,) = h.set_parameters(NODE, {"start_settle_s": 1.0})  # the check can pass: other parameters still set
    assert allowed.successful


def test_a_silent_clock_is_logged_throttled_with_what_the_node_waits_for(tmp_path):
    """Lockstep without a plant: the node says it waits for a clock, naming the topic, at most once per 5 s."""
    timeout_s = 0.3  # checked every 0.15 s: unthrottled, some 13 lines in 2 s
    with NodeGroup(log_dir=tmp_path) as group:
        node = group.start("trajectory_node", ros_args(None, {"mode": "lockstep", "clock_timeout_s": timeout_s})
                           + ["-r", "__ns:=/silent", "-r", "/clock:=/silent/clock"])  # no tick from other tests

        def warnings() -> list[str]:
            text = node.stdout_path.read_text() + node.stderr_path.read_text()
            return [line for line in text.splitlines() if "no clock on" in line]

        deadline = time.monotonic() + 30.0
        while not warnings() and time.monotonic() < deadline:
            time.sleep(0.1)
        first_seen = time.monotonic()
        assert warnings(), node.stderr_tail()
        time.sleep(2.0)
        lines = warnings()
        elapsed = time.monotonic() - first_seen
    assert "WARN" in lines[0] and "no clock on /silent/clock for" in lines[0]
    assert "(last tick: none)" in lines[0] and "0 publisher(s) of /silent/clock" in lines[0]
    assert 1 <= len(lines) <= 2 + elapsed / 5.0  # throttled to one line per 5 s


@pytest.mark.parametrize("override, name", [
    ({"scenario": "point-to-point", "waypoints": [1.0, 2.0, 3.0, 4.0]}, "waypoints"),
    ({"scenario": "paper-circle", "waypoints": [1.0, 2.0, 3.0]}, "waypoints"),
    ({"scenario": "spiral"}, "scenario"),
    ({"start_settle_s": 120.0}, "start_settle_s"),
    ({"clock_timeout_s": 0.0}, "clock_timeout_s"),
    ({"mode": "lockstep", "preview_every": 2}, "preview_every"),
    ({"preview_every": 0}, "preview_every"),
])
def test_refuses_to_start_with_a_bad_parameter(override, name):
    proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc.nodes.trajectory_node",
                           *ros_args(None, override)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert name in proc.stderr and "Traceback" not in proc.stderr
