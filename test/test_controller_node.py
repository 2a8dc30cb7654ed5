"""The controller node alone over DDS: a harness feeds odometry and previews and checks voltages and diagnostics."""

import math
import subprocess
import sys

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.control.blend import ReferenceBlend
from robotino_geom_mpc.control.motion_controller import MotionController, odometry_state_floats
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference, preview
from robotino_geom_mpc.ros.messages import ns_to_stamp, stamp_to_ns, yaw_to_quaternion
from robotino_geom_mpc.ros.qos import PUBLISH_QOS
from harness import Harness
from robotino_geom_mpc.system.processes import NodeGroup, ros_args
from robotino_geom_mpc.ros.messages import preview_message

pytestmark = pytest.mark.ros

NODE = "robotino_controller"


def odometry(stamp_ns, x, y, theta, vx_body=0.0, vy_body=0.0, wz=0.0):
    msg = Odometry()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation = yaw_to_quaternion(theta)
    msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.angular.z = vx_body, vy_body, wz
    return msg


def moving_odometry(stamp_ns, reference, t_s, dx=0.0):
    """Odometry at the reference's pose at t_s (x + dx) with its velocity (twist in base_link), and its state X."""
    (x, y, th), (vx, vy, w) = (row[0] for row in reference.sample(np.array([t_s]))[:2])
    c, s = math.cos(th), math.sin(th)
    msg = odometry(stamp_ns, x + dx, y, th, c * vx + s * vy, -s * vx + c * vy, w)
    return msg, np.array(odometry_state_floats((x + dx, y, th), (c * vx + s * vy, -s * vx + c * vy, w)))


def start_blend(reference, X, t0, control, limits=(0.3, 1.0)):
    """The blend a controller engages at its first tick t0 (`control.blend`, itself tested against its definition)."""
    pos, vel, acc, _ = reference.sample(np.array([t0]))
    return ReferenceBlend.engage(t0, X[0::2] - pos[0], X[1::2] - vel[0], -acc[0], *limits, control.period_s)


def blended_preview(reference, blend, t, control):
    """`reference.trajectories.preview` at t plus the blend's offsets at t + j Ts."""
    times = t + control.period_s * np.arange(1, control.horizon + 1)
    return preview(reference, t, control.period_s, control.horizon) + blend.offset(times)


def stamped_preview(reference, reference_t_ns, stamp_ns, control):
    """The preview of the reference at `reference_t_ns`, stamped `stamp_ns` (realtime: stamps near the node clock)."""
    msg = preview_message(reference, reference_t_ns, control.period_s, control.horizon)
    msg.header.stamp = ns_to_stamp(stamp_ns)
    return msg


def values(diag):
    (status,) = diag.status
    return status, {kv.key: kv.value for kv in status.values}


@pytest.fixture(scope="module")
def harness():
    with Harness("controller_test") as h:
        h.voltages = h.collect("wheel_voltages", Float64MultiArray)
        h.diagnostics = h.collect("diagnostics", DiagnosticArray)
        h.odom_pub = h.node.create_publisher(Odometry, "odom", PUBLISH_QOS)
        h.preview_pub = h.node.create_publisher(MultiDOFJointTrajectory, "reference_preview", PUBLISH_QOS)
        yield h


@pytest.fixture(scope="module")
def lockstep_controller(harness, tmp_path_factory):
    with NodeGroup(log_dir=tmp_path_factory.mktemp("controller")) as group:
        node = group.start("controller_node", ros_args(None, {"mode": "lockstep"}))
        h = harness
        assert h.spin_until(lambda: h.odom_pub.get_subscription_count() >= 1
                            and h.preview_pub.get_subscription_count() >= 1
                            and h.node.count_publishers("wheel_voltages") >= 1, 30.0), node.stderr_tail()
        yield node


def test_lockstep_voltages_equal_the_core_controller(harness, lockstep_controller):
    """The first tick starts the tracking off the reference: the core controller on the blended preview."""
    h = harness
    robot, control = load_params()
    Ts_ns = round(control.period_s * 1e9)
    reference = make_reference("lemniscate")
    core = MotionController(robot, control)
    blend = None
    # measured states: a little off the reference, turning, moving (twist in base_link)
    states = []
    for k in range(3):
        x, y, th = reference.position((100 + k) * control.period_s)
        states.append((x + 0.002, y - 0.001 * k, th + 0.01, 0.1, 0.05 - 0.01 * k, 0.2))
    start_v, start_d = len(h.voltages), len(h.diagnostics)
    for k, (x, y, th, vxb, vyb, wz) in enumerate(states):
        stamp = (100 + k) * Ts_ns
        if k == 1:  # odometry before its preview: the controller waits for the preview of the same stamp
            h.odom_pub.publish(odometry(stamp, x, y, th, vxb, vyb, wz))
            h.spin_for(0.3)
            assert len(h.voltages) == start_v + 1
            h.preview_pub.publish(preview_message(reference, stamp, control.period_s, control.horizon))
        else:
            h.preview_pub.publish(preview_message(reference, stamp, control.period_s, control.horizon))
            h.spin_for(0.1)
            h.odom_pub.publish(odometry(stamp, x, y, th, vxb, vyb, wz))
        assert h.spin_until(lambda: len(h.voltages) >= start_v + k + 1 and len(h.diagnostics) >= start_d + k + 1)
        c, s = math.cos(th), math.sin(th)
        X = np.array([x, c * vxb - s * vyb, y, s * vxb + c * vyb, th, wz])
        t = stamp * 1e-9
        if blend is None:  # o(t0) = measured - reference, o'(t0) likewise, o''(t0) = -reference acceleration
            blend = start_blend(reference, X, t, control)
        out = core.step(X, blended_preview(reference, blend, t, control))
        got = h.voltages[start_v + k]
        assert list(got.layout.dim)[0].size == 3
        assert np.allclose(got.data, out.voltages, rtol=1e-12, atol=1e-12)
        diag = h.diagnostics[start_d + k]
        assert stamp_to_ns(diag.header.stamp) == stamp
        status, kv = values(diag)
        error = np.array([x, y, th]) - reference.position(t)
        for axis, e in zip(("error_x_m", "error_y_m", "error_theta_rad"), error):
            assert float(kv[axis]) == pytest.approx(e, rel=1e-8, abs=1e-12)
        assert kv["saturated"] == str(bool(out.saturated)).lower()
        assert kv["infeasible"] == "false" and float(kv["compute_time_ms"]) >= 0.0
        assert float(kv["blend_remaining_s"]) == pytest.approx(blend.remaining_s(t), abs=1e-4)
        assert kv["blend_engagements"] == "1" and float(kv["dt_s"]) == control.period_s
    # a resent odometry stamp that was answered already gets no second answer
    h.odom_pub.publish(odometry(stamp, *states[-1]))
    h.spin_for(0.3)
    assert len(h.voltages) == start_v + len(states)


def test_an_answer_sent_before_the_plant_matched_goes_out_when_it_matches(tmp_path_factory):
    """Lockstep: the answer to a tick published while no plant listened is delivered once one subscribes."""
    robot, control = load_params()
    stamp = 40 * round(control.period_s * 1e9)
    reference = make_reference("paper-circle")
    with NodeGroup(log_dir=tmp_path_factory.mktemp("late")) as group, Harness("late_plant") as h:
        node = group.start("controller_node", ros_args(None, {"mode": "lockstep"}) + ["-r", "__ns:=/late"])
        odom_pub = h.node.create_publisher(Odometry, "/late/odom", PUBLISH_QOS)
        preview_pub = h.node.create_publisher(MultiDOFJointTrajectory, "/late/reference_preview", PUBLISH_QOS)
        assert h.spin_until(lambda: odom_pub.get_subscription_count() >= 1
                            and preview_pub.get_subscription_count() >= 1, 30.0), node.stderr_tail()
        x, y, th = reference.position(stamp * 1e-9)
        preview_pub.publish(preview_message(reference, stamp, control.period_s, control.horizon))
        h.spin_for(0.1)
        odom_pub.publish(odometry(stamp, x + 0.001, y, th))
        h.spin_for(0.5)  # answered with nobody listening
        voltages = h.collect("/late/wheel_voltages", Float64MultiArray)
        assert h.spin_until(lambda: len(voltages) >= 1, 10.0), "the undelivered answer did not go out on match"
        h.spin_for(0.3)
    assert len(voltages) == 1  # once
    X = np.array([x + 0.001, 0.0, y, 0.0, th, 0.0])
    out = MotionController(robot, control).step(
        X, blended_preview(reference, start_blend(reference, X, stamp * 1e-9, control), stamp * 1e-9, control))
    assert np.allclose(voltages[0].data, out.voltages, rtol=1e-12, atol=1e-12)


def test_topics_and_qos(harness, lockstep_controller):
    graph = dict(harness.node.get_topic_names_and_types())
    assert graph["/wheel_voltages"] == ["std_msgs/msg/Float64MultiArray"]
    assert graph["/diagnostics"] == ["diagnostic_msgs/msg/DiagnosticArray"]
    (info,) = [i for i in harness.node.get_publishers_info_by_topic("/wheel_voltages") if i.node_name == NODE]
    assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    assert info.qos_profile.durability == DurabilityPolicy.VOLATILE


def test_nan_odometry_gives_zero_volts_and_an_error_diagnostic(harness, lockstep_controller):
    h = harness
    _, control = load_params()
    stamp = 500 * round(control.period_s * 1e9)
    h.preview_pub.publish(preview_message(make_reference("paper-circle"), stamp, control.period_s, control.horizon))
    start_v, start_d = len(h.voltages), len(h.diagnostics)
    h.odom_pub.publish(odometry(stamp, math.nan, 0.0, 0.0))
    assert h.spin_until(lambda: len(h.voltages) > start_v and len(h.diagnostics) > start_d)
    assert list(h.voltages[start_v].data) == [0.0, 0.0, 0.0]
    status, kv = values(h.diagnostics[start_d])
    assert status.level == DiagnosticStatus.ERROR and "non-finite" in status.message
    assert int(kv["rejected"]) >= 1


def test_wrongly_sized_preview_is_rejected(harness, lockstep_controller):
    h = harness
    _, control = load_params()
    stamp = 600 * round(control.period_s * 1e9)
    bad = preview_message(make_reference("paper-circle"), stamp, control.period_s, control.horizon + 2)
    start_v, start_d = len(h.voltages), len(h.diagnostics)
    h.preview_pub.publish(bad)
    h.spin_for(0.1)
    h.odom_pub.publish(odometry(stamp, 0.0, 0.0, 0.0))
    assert h.spin_until(lambda: len(h.voltages) > start_v and len(h.diagnostics) > start_d)
    h.spin_for(0.3)
    # no answer computed from it: the tick gets zero volts once, the diagnostics name the reason
    assert [list(v.data) for v in h.voltages[start_v:]] == [[0.0, 0.0, 0.0]]
    status, kv = values(h.diagnostics[-1])
    assert status.level == DiagnosticStatus.ERROR and "preview_size" in status.message
    assert kv["last_refusal"] == "preview_size"


def test_parameter_set_is_validated_and_refusal_keeps_the_old_value(harness, lockstep_controller):
    h = harness
    (bad,) = h.set_parameters(NODE, {"control.horizon": 0})
    assert not bad.successful and "control.horizon" in bad.reason
    (bad_choice,) = h.set_parameters(NODE, {"control.mode": "fuzzy"})
    assert not bad_choice.successful and "control.mode" in bad_choice.reason
    (fixed,) = h.set_parameters(NODE, {"mode": "realtime"})
    assert not fixed.successful and "restart" in fixed.reason
    (exclusive,) = h.set_parameters(NODE, {"robot.mass_kg": 0.0})
    assert not exclusive.successful and "> 0" in exclusive.reason
    assert h.get_parameters(NODE, ["control.horizon", "control.mode", "robot.mass_kg", "mode"]) == [
        4, "closed_form", 21.4, "lockstep"]
    (good,) = h.set_parameters(NODE, {"control.q_x": 2.0e6})
    assert good.successful
    assert h.get_parameters(NODE, ["control.q_x"]) == [2.0e6]


def _rig(h, namespace: str):
    """The test's side of a controller in `namespace`: collected voltages and diagnostics, odometry and preview
    publishers.
    """
    return (h.collect(f"{namespace}/wheel_voltages", Float64MultiArray),
            h.collect(f"{namespace}/diagnostics", DiagnosticArray),
            h.node.create_publisher(Odometry, f"{namespace}/odom", PUBLISH_QOS),
            h.node.create_publisher(MultiDOFJointTrajectory, f"{namespace}/reference_preview", PUBLISH_QOS))


def test_realtime_watchdog_outputs_zero_volts_on_stale_odometry(harness, tmp_path_factory):
    """In a namespace (relative topic names), apart from the lockstep controller."""
    h = harness
    _, control = load_params()
    reference = make_reference("paper-circle")
    voltages, diagnostics, odom_pub, preview_pub = _rig(h, "/rt")
    with NodeGroup(log_dir=tmp_path_factory.mktemp("controller_rt")) as group:
        args = ros_args(None, {"mode": "realtime", "odom_timeout_s": 0.2, "reference_timeout_s": 0.2})
        node = group.start("controller_node", [*args, "-r", "__ns:=/rt"])
        assert h.spin_until(lambda: odom_pub.get_subscription_count() >= 1
                            and preview_pub.get_subscription_count() >= 1
                            and h.node.count_publishers("/rt/wheel_voltages") >= 1, 30.0), node.stderr_tail()
        h.spin_for(0.2)

        def tracking():
            return sum(values(d)[0].message == "tracking" for d in diagnostics)

        k = 0
        while tracking() < 5 and k < 200:  # the first messages can arrive late (discovery): refused as stale
            stamp = h.node.get_clock().now().nanoseconds
            preview_pub.publish(stamped_preview(reference, k * round(control.period_s * 1e9), stamp, control))
            odom_pub.publish(odometry(stamp, 0.001, 0.0, 0.0))
            h.spin_for(0.03)
            k += 1
        assert tracking() >= 5, node.stderr_tail()
        count = len(voltages)
        h.spin_for(1.0)  # nothing arrives: stale after 0.2 s
        data = [list(m.data) for m in voltages]
        assert data[count - 1] != [0.0, 0.0, 0.0]  # the last answer
        zeros = data[count:]  # then only the watchdog's zero volts
        assert len(zeros) >= 2 and all(d == [0.0, 0.0, 0.0] for d in zeros)
        states = [values(d)[1]["watchdog"] for d in diagnostics]
        assert "stale_odom" in states


def test_realtime_moves_the_freshest_preview_to_the_odometry_stamp(harness, tmp_path_factory):
    """The trajectory's and the plant's timers are out of phase: a preview 7 ms older than the odometry is moved.

    A first tick (odometry and preview of one stamp) starts the controller and its blend; the second comes
    after the blend is over, 0.4 s later, with a preview 7 ms older than its odometry.
    """
    h = harness
    robot, control = load_params()
    reference = make_reference("lemniscate")
    first_t = 500 * round(control.period_s * 1e9)  # reference times
    preview_t = first_t + 400_000_000
    t = preview_t + 7_000_000
    first_odom, X1 = moving_odometry(0, reference, first_t * 1e-9, 0.001)
    second_odom, X = moving_odometry(0, reference, t * 1e-9, 0.001)
    limits = (50.0, 500.0)  # a short blend
    voltages, diagnostics, odom_pub, preview_pub = _rig(h, "/shift")
    with NodeGroup(log_dir=tmp_path_factory.mktemp("controller_shift")) as group:
        # long timeouts: Fast DDS can hold the first messages between two participants 333 ms (bench/README.md)
        node = group.start("controller_node", [*ros_args(None, {
            "mode": "realtime", "odom_timeout_s": 2.0, "reference_timeout_s": 2.0,
            "blend_acceleration_mps2": limits[0], "blend_acceleration_radps2": limits[1]}), "-r", "__ns:=/shift"])
        assert h.spin_until(lambda: odom_pub.get_subscription_count() >= 1
                            and preview_pub.get_subscription_count() >= 1
                            and h.node.count_publishers("/shift/wheel_voltages") >= 1, 30.0), node.stderr_tail()
        h.spin_for(0.2)
        for _ in range(10):  # the first messages can arrive late (discovery): refused as stale, then sent again
            base = h.node.get_clock().now().nanoseconds - first_t  # stamp = base + reference time
            preview_pub.publish(stamped_preview(reference, first_t, base + first_t, control))
            h.spin_for(0.05)
            first_odom.header.stamp = ns_to_stamp(base + first_t)
            odom_pub.publish(first_odom)
            if h.spin_until(lambda: any(values(d)[0].message == "tracking" for d in diagnostics), 1.0):
                break
        voltages.clear()
        diagnostics.clear()
        h.spin_until(lambda: h.node.get_clock().now().nanoseconds > base + preview_t, 2.0)
        preview_pub.publish(stamped_preview(reference, preview_t, base + preview_t, control))
        h.spin_for(0.05)
        second_odom.header.stamp = ns_to_stamp(base + t)
        odom_pub.publish(second_odom)
        assert h.spin_until(lambda: voltages and diagnostics), node.stderr_tail()
    blend = start_blend(reference, X1, first_t * 1e-9, control, limits)
    assert blend.duration_s < 0.3  # over at the second tick

    def second_tick(reference_t_ns):
        core = MotionController(robot, control)
        core.step(X1, blended_preview(reference, blend, first_t * 1e-9, control))
        return core.step(X, preview(reference, reference_t_ns * 1e-9, control.period_s, control.horizon),
                         (t - first_t) * 1e-9).voltages

    exact, unmoved = second_tick(t), second_tick(preview_t)
    got = np.array(voltages[0].data)
    assert np.max(np.abs(got - exact)) < 1e-3
    assert np.max(np.abs(got - unmoved)) > 100 * np.max(np.abs(got - exact))
    _, kv = values(diagnostics[0])
    assert float(kv["error_x_m"]) == pytest.approx(0.001, abs=1e-7)  # against x_d at the odometry stamp
    assert abs(float(kv["error_y_m"])) < 1e-7
    assert float(kv["dt_s"]) == pytest.approx((t - first_t) * 1e-9, abs=1e-12)


def test_refuses_to_start_with_an_out_of_range_horizon():
    proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc.nodes.controller_node",
                           *ros_args(None, {"control.horizon": 0})], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "control.horizon" in proc.stderr and "Traceback" not in proc.stderr


def _quaternion_odometry(stamp, q):
    msg = odometry(stamp, 0.001, 0.0, 0.0)
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    return msg


@pytest.mark.parametrize("what, q, reason", [
    ("odom", (0.0, 0.0, 0.0, 0.0), "quaternion_norm"),  # was read as yaw 0
    ("odom", (0.0, 0.0, 0.5, 0.5), "quaternion_norm"),  # was read as pi/2 (atan2 of an unnormalised quaternion)
    ("odom", (0.1, 0.0, 0.0, math.sqrt(1 - 0.01)), "quaternion_tilt"),  # 0.2 rad of roll
    ("reference_preview", (0.0, 0.0, 0.0, 0.0), "preview_quaternion_norm"),
    ("reference_preview", (0.0, 0.06, 0.0, math.sqrt(1 - 0.0036)), "preview_quaternion_tilt"),
])
def test_a_quaternion_that_is_no_yaw_is_refused_with_zero_volts(harness, lockstep_controller, what, q, reason):
    h = harness
    _, control = load_params()
    Ts_ns = round(control.period_s * 1e9)
    stamp = (700 + 10 * len(h.voltages)) * Ts_ns  # a new tick per case
    msg = preview_message(make_reference("paper-circle"), stamp, control.period_s, control.horizon)
    if what == "reference_preview":
        r = msg.points[2].transforms[0].rotation
        r.x, r.y, r.z, r.w = q
    start_v, start_d = len(h.voltages), len(h.diagnostics)
    rejected = None
    h.preview_pub.publish(msg)
    h.spin_for(0.1)
    h.odom_pub.publish(_quaternion_odometry(stamp, q) if what == "odom" else odometry(stamp, 0.001, 0.0, 0.0))
    assert h.spin_until(lambda: len(h.voltages) > start_v and any(
        values(d)[0].level == DiagnosticStatus.ERROR for d in h.diagnostics[start_d:]))
    assert list(h.voltages[start_v].data) == [0.0, 0.0, 0.0]
    status, kv = [values(d) for d in h.diagnostics[start_d:] if values(d)[0].level == DiagnosticStatus.ERROR][-1]
    assert reason in status.message and kv["last_refusal"] == reason
    rejected = int(kv["rejected"])
    assert rejected >= 1


def test_unstable_weights_and_the_period_or_horizon_cannot_be_set(harness, lockstep_controller):
    h = harness
    (unstable,) = h.set_parameters(NODE, {"control.q_x": 1.0e3})  # q/r = 3.3e3 with N = 4: a pole outside
    assert not unstable.successful and "unstable" in unstable.reason.lower() and "x" in unstable.reason
    for name, value in (("control.period_s", 0.02), ("control.horizon", 6)):
        (fixed,) = h.set_parameters(NODE, {name: value})
        assert not fixed.successful and name in fixed.reason and "restart" in fixed.reason
    assert h.get_parameters(NODE, ["control.q_x", "control.period_s", "control.horizon"])[1:] == [0.01, 4]


def test_lockstep_controller_says_what_it_waits_for(tmp_path_factory):
    """Alone in lockstep it logs (throttled) that no odometry came; then that a tick waits for its preview."""
    _, control = load_params()
    with NodeGroup(log_dir=tmp_path_factory.mktemp("wait")) as group, Harness("wait_plant") as h:
        node = group.start("controller_node", ros_args(None, {"mode": "lockstep"}) + ["-r", "__ns:=/wait"])

        def log():
            return node.stdout_path.read_text() + node.stderr_path.read_text()

        odom_pub = h.node.create_publisher(Odometry, "/wait/odom", PUBLISH_QOS)
        assert h.spin_until(lambda: "waiting: no odometry on /wait/odom" in log(), 30.0), node.stderr_tail()
        assert h.spin_until(lambda: odom_pub.get_subscription_count() >= 1, 30.0)
        stamp = 3 * round(control.period_s * 1e9)
        odom_pub.publish(odometry(stamp, 0.0, 0.0, 0.0))
        assert h.spin_until(lambda: f"odometry of stamp {stamp} ns waits" in log(), 10.0), node.stderr_tail()
        assert "reference_preview of that stamp on /wait/reference_preview" in log()


def test_realtime_stamps_are_checked_against_the_node_clock(harness, tmp_path_factory):
    """Stale (an hour old, zero), future: refused with zero volts; older than the last used: dropped, then the
    watchdog's zero volts (no valid input left within the timeout).
    """
    h = harness
    _, control = load_params()
    reference = make_reference("paper-circle")
    voltages, diagnostics, odom_pub, preview_pub = _rig(h, "/stamps")
    hour = 3600 * 10**9

    def now():
        return h.node.get_clock().now().nanoseconds

    def send(odom_stamp):
        """A fresh preview, then odometry of `odom_stamp`; returns what came back (voltages, diagnostics)."""
        v0, d0 = len(voltages), len(diagnostics)
        t = now()
        preview_pub.publish(preview_message(reference, t, control.period_s, control.horizon))
        h.spin_for(0.01)
        odom_pub.publish(odometry(odom_stamp(t), 0.001, 0.0, 0.0))
        h.spin_until(lambda: len(diagnostics) > d0, 2.0)
        h.spin_for(0.02)
        return [list(v.data) for v in voltages[v0:]], [values(d) for d in diagnostics[d0:]]

    with NodeGroup(log_dir=tmp_path_factory.mktemp("stamps")) as group:
        node = group.start("controller_node", [*ros_args(None, {"mode": "realtime", "odom_timeout_s": 1.0,
                                                                 "reference_timeout_s": 1.0}), "-r", "__ns:=/stamps"])
        assert h.spin_until(lambda: odom_pub.get_subscription_count() >= 1
                            and preview_pub.get_subscription_count() >= 1
                            and h.node.count_publishers("/stamps/wheel_voltages") >= 1, 30.0), node.stderr_tail()
        h.spin_for(0.3)
        for _ in range(10):  # the first messages can arrive late (discovery): refused as stale, then sent again
            ok_v, ok_d = send(lambda t: t)
            if ok_d and ok_d[0][0].message == "tracking":
                break
        assert len(ok_v) == 1 and ok_v[0] != [0.0] * 3 and ok_d[0][0].message == "tracking", (ok_v, ok_d)
        refused = int(ok_d[0][1]["rejected"])
        for name, shifted, reason in (("an hour old", lambda t: t - hour, "stale"), ("zero", lambda t: 0, "stale"),
                                      ("1 s ahead", lambda t: t + 10**9, "future")):
            got_v, got_d = send(shifted)
            assert got_v == [[0.0] * 3], name
            (status, kv), = got_d
            assert status.level == DiagnosticStatus.ERROR and reason in status.message, name
            assert kv["last_refusal"] == reason, name
        assert int(kv["rejected"]) == refused + 3
        ok_v, _ = send(lambda t: t)  # a valid tick, then one 5 ms older than it: dropped, no answer
        assert len(ok_v) == 1 and ok_v[0] != [0.0] * 3
        newest = now()
        v0 = len(voltages)
        preview_pub.publish(preview_message(reference, newest, control.period_s, control.horizon))
        odom_pub.publish(odometry(newest, 0.001, 0.0, 0.0))
        h.spin_for(0.05)
        d0 = len(diagnostics)
        odom_pub.publish(odometry(newest - 5_000_000, 0.001, 0.0, 0.0))
        assert h.spin_until(lambda: any(values(d)[0].message == "dropped odom (old)" for d in diagnostics[d0:]), 2.0)
        assert len(voltages) == v0 + 1  # only the answer to the newest tick
        status, kv = [values(d) for d in diagnostics[d0:] if values(d)[0].message == "dropped odom (old)"][0]
        assert status.level == DiagnosticStatus.WARN and kv["dropped_old"] == "1"
        assert h.spin_until(lambda: len(voltages) > v0 + 1, 3.0)  # nothing valid within 1 s: the watchdog
        assert list(voltages[v0 + 1].data) == [0.0] * 3


def test_diagnostics_bytes_decode_as_the_message_they_stand_for():
    """`diagnostics_cdr` against rclpy's deserializer and rosbags' (every string length mod 4, non-ASCII)."""
    import random

    from diagnostic_msgs.msg import KeyValue
    from rclpy.serialization import deserialize_message
    from rosbags.typesys import Stores, get_typestore

    from robotino_geom_mpc.nodes.controller_outputs import STATUS_NAME, diagnostics_cdr

    store, rng = get_typestore(Stores.ROS2_JAZZY), random.Random(4)
    for case in range(40):
        keys = [f"k{'x' * rng.randrange(6)}" for _ in range(rng.randrange(16))]
        values = [rng.choice(["", "é", "3.14159", "true", "x" * rng.randrange(9)]) for _ in keys]
        message, level, stamp = "tracking" + "°" * (case % 5), bytes([case % 4]), rng.randrange(2**40)
        data = diagnostics_cdr(stamp, level, message, [k.encode() for k in keys], values)
        expected = DiagnosticArray(status=[DiagnosticStatus(
            level=level, name=STATUS_NAME, message=message, hardware_id="robotino",
            values=[KeyValue(key=k, value=v) for k, v in zip(keys, values)])])
        expected.header.stamp.sec, expected.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        assert deserialize_message(data, DiagnosticArray) == expected
        other = store.deserialize_cdr(data, "diagnostic_msgs/msg/DiagnosticArray")
        assert [(p.key, p.value) for p in other.status[0].values] == list(zip(keys, values))
        assert (other.status[0].message, other.header.stamp.nanosec) == (message, stamp % 1_000_000_000)
