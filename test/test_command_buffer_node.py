"""The robot-side command buffer node in front of a stand-in driver (an rclpy subscriber recording when each twist
was sent: its DDS source timestamp, the writer's clock at the write, not the stand-in's own scheduling, which a
loaded host delayed by 0.2 s), against the plans' times: newest plan first, late plans covered, older/duplicate
ignored, bad plans refused, zero twist when the plans are used up, reports of what was applied and when each plan
arrived.
"""

import math

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

from harness import Harness
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.ros.plans import plan_message, report_of_message
from robotino_geom_mpc.ros.qos import PUBLISH_QOS
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

pytestmark = pytest.mark.ros

TS = 0.1  # a long period: each twist is checked against its own period, on a loaded machine too
IDLE_S = 0.3


def _plan(basis, first, values):
    return CommandPlan(basis, tuple(first + i * TS for i in range(len(values))), tuple(values), TS)


@pytest.fixture(scope="module")
def buffer_run(tmp_path_factory):
    """Plans sent to a buffer node; the twists with their send times (robot clock), the reports."""
    with NodeGroup(log_dir=tmp_path_factory.mktemp("buffer")) as group, Harness("stand_in_driver") as h:
        twists = []  # (sent [s], (vx, vy, w))
        reports = h.collect("command_applied", JointTrajectory)
        diagnostics = h.collect("diagnostics", DiagnosticArray)
        now = lambda: h.node.get_clock().now().nanoseconds * 1e-9  # noqa: E731 - the robot's clock (one host)
        h.node.create_subscription(Twist, "cmd_vel", lambda m, info: twists.append(
            (info["source_timestamp"] * 1e-9, (m.linear.x, m.linear.y, m.angular.z))), 100)
        pub = h.node.create_publisher(MultiDOFJointTrajectory, "cmd_vel_plan", PUBLISH_QOS)
        node = group.start("command_buffer_node", ros_args(None, {"control.period_s": TS, "idle_after_s": IDLE_S}))
        assert h.spin_until(lambda: pub.get_subscription_count() >= 1 and h.node.count_publishers("cmd_vel") >= 1,
                            30.0), node.stderr_tail()
        h.spin_for(0.5)
        t0 = now() + 0.3
        first = _plan(t0 - 0.05, t0, [(0.1 * (i + 1), 0.0, 0.0) for i in range(6)])  # entries 0.1 .. 0.6
        # a newer plan from entry 4 on (basis later), sent before the first one's entry 4
        newer = _plan(t0 + 0.05, t0 + 4 * TS, [(0.0, 0.2 * (i + 1), 0.0) for i in range(4)])
        bad = [
            _plan(t0 + 0.06, t0 + 5 * TS, [(math.nan, 0.0, 0.0)] * 3),  # NaN
            CommandPlan(t0 + 0.07, (t0 + 5 * TS, t0 + 5 * TS), ((9.0, 0, 0),) * 2, TS),  # non-increasing times
            _plan(t0 + 30.0, t0 + 30.0, [(9.0, 0.0, 0.0)] * 3),  # far in the future
            _plan(t0 - 30.0, t0 - 30.0, [(9.0, 0.0, 0.0)] * 3),  # far in the past
        ]
        pub.publish(plan_message(first, "cmd_vel"))
        assert h.spin_until(lambda: now() >= t0 + 1.5 * TS, 5.0)
        assert now() < t0 + 3.5 * TS, "the stand-in was too slow to send the newer plan in time"
        wrong_length = plan_message(newer, "cmd_vel")
        wrong_length.header.stamp.sec += 1
        wrong_length.points[1].velocities = []
        # the newer plan, then the first again (older than the newest: ignored), the newer again (duplicate)
        for msg in [plan_message(p, "cmd_vel") for p in (newer, first, newer)] + [wrong_length] + [
                plan_message(p, "cmd_vel") for p in bad]:
            pub.publish(msg)
            h.spin_for(0.002)  # apart: the buffer's subscription keeps the newest few
        end = newer.end_s
        assert h.spin_until(lambda: now() > end + IDLE_S + 4 * TS, 10.0)
        sent = now()
        assert h.spin_until(lambda: any(d.header.stamp.sec + d.header.stamp.nanosec * 1e-9 > sent
                                        for d in diagnostics), 5.0)
        group.stop(5.0)
    counts = {kv.key: kv.value for kv in diagnostics[-1].status[0].values}
    return t0, first, newer, twists, [report_of_message(m) for m in reports], counts


def test_each_twist_goes_out_in_its_entry_period_from_the_newest_plan(buffer_run):
    t0, first, newer, twists, _, counts = buffer_run
    moving = [(t, v) for t, v in twists if v != (0.0, 0.0, 0.0)]
    expected = [(first.times_s[i], first.entries[i]) for i in range(4)] + list(zip(newer.times_s, newer.entries))
    assert [v for _, v in moving] == [pytest.approx(v) for _, v in expected]
    for (sent, _), (start, _) in zip(moving, expected):
        assert start <= sent < start + TS, (sent - start, "each twist goes out within its own period")


def test_the_robot_stops_when_the_plans_are_used_up_then_idles(buffer_run):
    t0, _, newer, twists, _, _ = buffer_run
    assert all(v == (0.0, 0.0, 0.0) for t, v in twists if t < t0)  # before the first entry: at rest
    zeros = [t for t, v in twists if v == (0.0, 0.0, 0.0) and t > t0]
    assert zeros and newer.end_s <= zeros[0] < newer.end_s + TS
    assert all(t < newer.end_s + IDLE_S + 2 * TS for t in zeros)  # then nothing until the next plan


def test_reports_say_what_was_applied_and_when_each_plan_arrived(buffer_run):
    t0, first, newer, twists, reports, _ = buffer_run
    receipts = [(r.basis_s, r.taken) for r in reports if r.values is None]
    # the first, the newer, the first again (older), the newer again (duplicate), then the refused ones
    assert [b for b, _ in receipts[:4]] == pytest.approx([first.basis_s, newer.basis_s, first.basis_s, newer.basis_s])
    assert [taken for _, taken in receipts] == [True, True] + [False] * (len(receipts) - 2)
    applied = [r for r in reports if r.values is not None and r.basis_s is not None]
    assert all(r.values == (0.0, 0.0, 0.0) for r in reports if r.values is not None and r.basis_s is None)
    assert [(r.entry_index, r.values) for r in applied] == [(i, pytest.approx(first.entries[i])) for i in range(4)] + [
        (i, pytest.approx(newer.entries[i])) for i in range(4)]
    for r in applied:
        plan = first if abs(r.basis_s - first.basis_s) < 1e-6 else newer
        assert plan.times_s[r.entry_index] <= r.time_s < plan.times_s[r.entry_index] + TS


def test_bad_plans_are_refused_and_counted_older_and_duplicates_ignored(buffer_run):
    counts = buffer_run[-1]
    assert {k: int(counts[f"refused_{k}"]) for k in ("nan", "times", "future", "past", "length")} == dict.fromkeys(
        ("nan", "times", "future", "past", "length"), 1)
    assert int(counts["refused"]) == 5 and int(counts["ignored_older_or_duplicate"]) == 2


def test_a_second_controllers_plans_are_refused_named_and_taken_after_a_release(tmp_path):
    """Two controllers' plans on one buffer (issue 38): the first to send is paired, the other's plans are refused
    (no receipt, counted, named in the diagnostics) until ``~/release``; then the other's next plan is taken.
    """
    from rclpy.node import Node
    from std_srvs.srv import Trigger

    with NodeGroup(log_dir=tmp_path) as group, Harness("first_controller") as h:
        second = Node("second_controller", context=h.context)
        h.executor.add_node(second)
        reports = h.collect("command_applied", JointTrajectory)
        diagnostics = h.collect("diagnostics", DiagnosticArray)
        pubs = [h.node.create_publisher(MultiDOFJointTrajectory, "cmd_vel_plan", PUBLISH_QOS)]
        release = h.node.create_client(Trigger, "/robotino_command_buffer/release")
        node = group.start("command_buffer_node", ros_args(None, {"control.period_s": TS, "idle_after_s": IDLE_S}))
        assert h.spin_until(lambda: pubs[0].get_subscription_count() >= 1, 30.0), node.stderr_tail()
        h.spin_for(0.5)
        now = lambda: h.node.get_clock().now().nanoseconds * 1e-9  # noqa: E731 - the robot's clock (one host)

        def send(pub, value: float) -> float:
            t = now()
            pub.publish(plan_message(_plan(t, t + TS, [(value, 0.0, 0.0)] * 3), "cmd_vel"))
            h.spin_for(0.15)
            return t

        def receipts() -> list:
            return [r.basis_s for r in map(report_of_message, reports) if r.values is None]

        def status() -> dict:
            return {kv.key: kv.value for kv in diagnostics[-1].status[0].values} if diagnostics else {}

        a1 = send(pubs[0], 0.1)  # paired (the only publisher on the graph then)
        pubs.append(second.create_publisher(MultiDOFJointTrajectory, "cmd_vel_plan", PUBLISH_QOS))
        assert h.spin_until(lambda: pubs[1].get_subscription_count() >= 1, 10.0)
        a1b = send(pubs[0], 0.1)
        send(pubs[1], 0.2)  # refused: the first controller holds the lease (0.5 s)
        a2 = send(pubs[0], 0.1)
        assert h.spin_until(lambda: status().get("refused_second_source") == "1", 5.0), str(status())
        assert "/second_controller" in status()["second_source"] and "first" not in status()["second_source"]
        assert "/first_controller" in status()["paired_source"] and "second" not in status()["paired_source"]
        answer = h._call(release, Trigger.Request(), 10.0)
        assert answer.success and "/first_controller" in answer.message, answer.message
        b = send(pubs[1], 0.2)  # the next controller to send takes the buffer
        a3 = send(pubs[0], 0.1)  # and the first is refused now
        assert h.spin_until(lambda: status().get("refused_second_source") == "2", 5.0), str(status())
        group.stop(5.0)
    assert receipts() == pytest.approx([a1, a1b, a2, b], abs=1e-5), (receipts(), a3)  # not the refused ones


def test_the_launchs_buffer_variant_closes_the_loop_with_the_buffer_as_the_only_cmd_vel_source(tmp_path, monkeypatch):
    """``command_buffer:=true command_interface:=cmd_vel`` (the robot side of docs/howto/real_robot_buffer.md in
    simulation): evaluated with the launch stand-ins and its nodes started as launch_ros would. The buffer is the
    only publisher of ``cmd_vel`` (the controller sends plans and no plain command, which on a real robot would
    reach the driver as a second, delayed source); until the disable the robot tracks paper-circle within 3 times
    the offline loop's RMS error with plans over a 0.5 ms link each way (the DDS hops; the controller's tracking
    errors, ideal odometry: measured 0.24 mm against 0.195 mm); after ``~/enable`` false the buffer sends zero
    within 0.15 s (the disabled controller's plan of zeros replaces the plans it holds, which would run for the
    lead plus 25 periods, 0.25 s and more). Read back with rosbags; ``regress`` replays every plan (it crashed on
    a cmd_vel plan recording, and did not follow the disable).
    """
    import time

    from rosbags.highlevel import AnyReader
    from std_srvs.srv import SetBool

    from launch_standins import REPO, evaluate, install, load_description, of
    from ros2_shim import _node_argv
    from robotino_geom_mpc.network.link import LinkParams
    from robotino_geom_mpc.offline.results import compute_metrics
    from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
    from robotino_geom_mpc.params.files import load_params
    from robotino_geom_mpc.recording.regress import regress_bag

    install(monkeypatch.setitem)
    bag = tmp_path / "bag"
    actions, _ = evaluate(load_description(REPO / "launch" / "robotino_geom_mpc.launch.py"),
                          {"command_buffer": "true", "command_interface": "cmd_vel", "duration": "8",
                           "record": "true", "bag": str(bag)}, lambda package: str(REPO))
    sources = set()
    with NodeGroup(log_dir=tmp_path / "logs") as group, Harness("observer") as h:
        enable = h.node.create_client(SetBool, "/robotino_controller/enable")
        nodes = {node.kwargs["executable"]: group.start(node.kwargs["executable"], _node_argv(node, tmp_path)[1:])
                 for node in of("Node", actions)}
        plant = nodes["plant_node"]
        odom = h.collect("/odom", Odometry)
        assert h.spin_until(lambda: len(odom) > 0, 30.0), plant.stderr_tail()
        start, disabled = time.monotonic(), None
        while plant.popen.poll() is None and time.monotonic() < start + 60.0:
            sources |= {(i.node_namespace, i.node_name) for i in h.node.get_publishers_info_by_topic("/cmd_vel")}
            if disabled is None and time.monotonic() > start + 6.0:
                disabled = enable.call_async(SetBool.Request(data=False))
            h.spin_for(0.2)
        assert plant.popen.poll() == 0, plant.stderr_tail()
        assert disabled is not None and disabled.done() and disabled.result().success
        group.stop(10.0)
    assert sources == {("/", "robotino_command_buffer")}
    errors, twists, off_at = [], [], None
    with AnyReader([bag]) as reader:
        for conn, log_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/controller_enabled" and not msg.data:
                off_at = log_ns
            elif conn.topic == "/cmd_vel":
                twists.append((log_ns, (msg.linear.x, msg.linear.y, msg.angular.z)))
            elif conn.topic == "/diagnostics":
                for st in msg.status:
                    if st.message == "tracking":
                        kv = {v.key: float(v.value) for v in st.values if v.key.startswith("error_")}
                        errors.append((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec,
                                       math.hypot(kv["error_x_m"], kv["error_y_m"])))
    assert off_at is not None
    tracked = [e for stamp, e in errors if errors[0][0] + 10**9 <= stamp < off_at]  # after a 1 s settle
    assert len(tracked) > 300
    robot, control = load_params()
    near = LinkParams(delay_s=0.0005, jitter_s=0.0, loss=0.0, burst_length=1.0, duplicate=0.0)
    offline = compute_metrics(run_scenario(RunConfig("paper-circle", robot, control, duration_s=8.0,
                                                     command_interface="cmd_vel", link_up=near, link_down=near)))
    rms = math.sqrt(sum(e * e for e in tracked) / len(tracked))
    assert rms <= 3.0 * offline["rms_position_error_m"], (rms, offline["rms_position_error_m"])
    assert any(any(v) for t, v in twists if t < off_at)  # it was moving
    late = [(t - off_at) * 1e-9 for t, v in twists if t > off_at + 0.15e9 and any(v)]
    assert not late, f"the buffer still sent motion {late[-1]:.3f} s after the disable"
    # regress recomputes every cmd_vel plan, the disabled ticks' plans of zeros too (the recorded statuses say
    # when the controller was disabled)
    result = regress_bag(bag)
    assert result.command == "cmd_vel_plan" and result.passed and result.compared >= 0.9 * result.ticks, result
