"""The controller node alone over DDS: a harness feeds odometry and previews and checks voltages and diagnostics.

The wiring, QoS, timers and processes; every case of the tick itself (refusals, stamps, the preview moved to the
odometry's stamp, restarts) is checked in-process against the loop in test_controller_loop.
"""

import math
import subprocess
import sys

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.control.blend import ReferenceBlend
from robotino_geom_mpc.control.motion_controller import MotionController
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


@pytest.mark.parametrize("readers", [1, 2])
def test_an_answer_is_held_until_the_command_has_its_readers_then_sent_once(tmp_path_factory, readers):
    """Lockstep: the answer to a tick goes out once the command publisher has matched ``lockstep_command_readers``:
    with 1, an answer computed while no plant listened is delivered when one subscribes; with 2, a recorder's
    reader matched first gets nothing until the plant's matches too (sent then, the plant would never get it:
    the hang of a 20-robot fleet's tick 0), then both get it once.
    """
    robot, control = load_params()
    stamp = 40 * round(control.period_s * 1e9)
    reference = make_reference("paper-circle")
    with NodeGroup(log_dir=tmp_path_factory.mktemp("late")) as group, Harness("late_plant") as h:
        node = group.start("controller_node", ros_args(None, {"mode": "lockstep", "lockstep_command_readers": readers})
                           + ["-r", "__ns:=/late"])
        odom_pub = h.node.create_publisher(Odometry, "/late/odom", PUBLISH_QOS)
        preview_pub = h.node.create_publisher(MultiDOFJointTrajectory, "/late/reference_preview", PUBLISH_QOS)
        early = h.collect("/late/wheel_voltages", Float64MultiArray) if readers == 2 else None  # a recorder's
        assert h.spin_until(lambda: odom_pub.get_subscription_count() >= 1
                            and preview_pub.get_subscription_count() >= 1
                            and (early is None or h.node.count_publishers("/late/wheel_voltages") >= 1), 30.0), \
            node.stderr_tail()
        h.spin_for(0.3)  # the recorder's reader matched by the controller's writer too
        x, y, th = reference.position(stamp * 1e-9)
        preview_pub.publish(preview_message(reference, stamp, control.period_s, control.horizon))
        h.spin_for(0.1)
        odom_pub.publish(odometry(stamp, x + 0.001, y, th))
        h.spin_for(0.5)  # answered, held: no reader, or the recorder's only
        assert early is None or early == []
        voltages = h.collect("/late/wheel_voltages", Float64MultiArray)  # the plant's
        assert h.spin_until(lambda: len(voltages) >= 1, 10.0), "the held answer did not go out on match"
        h.spin_for(0.3)
    assert len(voltages) == 1 and (early is None or len(early) == 1)  # once each
    X = np.array([x + 0.001, 0.0, y, 0.0, th, 0.0])
    out = MotionController(robot, control).step(
        X, blended_preview(reference, start_blend(reference, X, stamp * 1e-9, control), stamp * 1e-9, control))
    for got in [voltages[0], *(early or [])]:
        assert np.allclose(got.data, out.voltages, rtol=1e-12, atol=1e-12)


def test_topics_and_qos(harness, lockstep_controller):
    graph = dict(harness.node.get_topic_names_and_types())
    assert graph["/wheel_voltages"] == ["std_msgs/msg/Float64MultiArray"]
    assert graph["/diagnostics"] == ["diagnostic_msgs/msg/DiagnosticArray"]
    # the node's name reaches the graph after its endpoints (ros_discovery_info): wait for it
    assert harness.spin_until(lambda: any(i.node_name == NODE for i in
                                          harness.node.get_publishers_info_by_topic("/wheel_voltages")), 10.0)
    (info,) = [i for i in harness.node.get_publishers_info_by_topic("/wheel_voltages") if i.node_name == NODE]
    assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    assert info.qos_profile.durability == DurabilityPolicy.VOLATILE


def _engagements_after_a_tick(h: Harness, stamp_ns: int) -> int:
    """One lockstep tick of paper-circle at `stamp_ns` (its preview, then an odometry near it): the count of bumpless
    (re)starts its ``tracking`` status reports.
    """
    _, control = load_params()
    reference = make_reference("paper-circle")
    start = len(h.diagnostics)
    h.preview_pub.publish(preview_message(reference, stamp_ns, control.period_s, control.horizon))
    h.spin_for(0.1)
    h.odom_pub.publish(odometry(stamp_ns, *(reference.position(stamp_ns * 1e-9) + [0.001, 0.0, 0.0])))

    def answered() -> list:
        return [kv for d in h.diagnostics[start:] for status, kv in [values(d)]
                if status.message == "tracking" and stamp_to_ns(d.header.stamp) == stamp_ns]
    assert h.spin_until(lambda: answered(), 10.0), [values(d)[0].message for d in h.diagnostics[start:]]
    return int(answered()[-1]["blend_engagements"])


def test_parameter_set_is_validated_and_refusal_keeps_the_old_value(harness, lockstep_controller):
    """Refused sets keep the old values; an accepted control parameter rebuilds the controller: the next tick
    restarts bumplessly (one engagement more; the restart itself: test_controller_loop_cases).
    """
    h = harness
    Ts_ns = round(load_params()[1].period_s * 1e9)
    before = _engagements_after_a_tick(h, 5000 * Ts_ns)  # (stamps after every other test's of this controller)
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
    assert _engagements_after_a_tick(h, 5001 * Ts_ns) == before  # refused sets: no rebuild
    (good,) = h.set_parameters(NODE, {"control.q_x": 2.0e6})
    assert good.successful
    assert h.get_parameters(NODE, ["control.q_x"]) == [2.0e6]
    assert _engagements_after_a_tick(h, 5002 * Ts_ns) == before + 1  # rebuilt: a bumpless restart


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


def test_refuses_to_start_with_an_out_of_range_horizon():
    proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc.nodes.controller_node",
                           *ros_args(None, {"control.horizon": 0})], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "control.horizon" in proc.stderr and "Traceback" not in proc.stderr


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
