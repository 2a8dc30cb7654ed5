"""The controller node against inputs that are well-formed but no measurement, and at its stop.

* A stamp that is no time (read by the node's decoder): refused with zero volts and an ERROR diagnostic
  naming the reason, the node alive. (Implausible twists, poses and previews, a twist just below the
  bound: test_controller_loop, in-process.)
* Parameter sets that cannot run (a timeout under two periods, a model T(theta) cannot be built on) are
  refused and the node keeps running.
* A preview in another frame (not the fast reader's layout: the general decoder) is refused, naming both
  frames (the other frames: test_controller_loop).
* Realtime under ``use_sim_time``: the watchdog counts simulated time (no stale data while the clock
  stands: the node hands the loop its clock as the watchdog's, the one DDS test of that wiring; the loop given
  either clock, a slow lockstep loop: test_controller_loop_cases); a clock that goes back (a bag played in a loop,
  a simulator reset) resumes the tracking once the watchdog has declared the data stale; before, every later
  input was dropped as older than the last used.
* Realtime: a controller stopped with SIGINT leaves the drives at zero volts.
"""

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import MultiDOFJointTrajectory

from harness import Harness
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.ros.messages import ns_to_stamp, preview_message, yaw_to_quaternion
from robotino_geom_mpc.system.processes import NodeGroup, ros_args
from robotino_geom_mpc.ros.qos import PUBLISH_QOS

pytestmark = pytest.mark.ros

NODE = "robotino_controller"


def _odometry(stamp_ns: int, x: float = 0.001, vx_body: float = 0.0) -> Odometry:
    msg = Odometry()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.pose.pose.position.x = x
    msg.pose.pose.orientation = yaw_to_quaternion(0.0)
    msg.twist.twist.linear.x = vx_body
    return msg


def _status(diag) -> tuple:
    (status,) = diag.status
    return status, {kv.key: kv.value for kv in status.values}


class Rig:
    """The test's side of one controller in `namespace`."""

    def __init__(self, h: Harness, namespace: str) -> None:
        self.h = h
        self.voltages = h.collect(f"{namespace}/wheel_voltages", Float64MultiArray)
        self.diagnostics = h.collect(f"{namespace}/diagnostics", DiagnosticArray)
        self.odom_pub = h.node.create_publisher(Odometry, f"{namespace}/odom", PUBLISH_QOS)
        self.preview_pub = h.node.create_publisher(MultiDOFJointTrajectory, f"{namespace}/reference_preview",
                                                   PUBLISH_QOS)
        self.namespace = namespace

    def start(self, group: NodeGroup, overrides: dict):
        node = group.start("controller_node", [*ros_args(None, overrides), "-r", f"__ns:={self.namespace}"])
        assert self.h.spin_until(lambda: self.odom_pub.get_subscription_count() >= 1
                                 and self.preview_pub.get_subscription_count() >= 1
                                 and self.h.node.count_publishers(f"{self.namespace}/wheel_voltages") >= 1,
                                 30.0), node.stderr_tail()
        self.h.spin_for(0.3)
        return node

    def tick(self, preview, odom) -> tuple[list, list]:
        """Publish a preview (if any) and an odometry; returns the voltages and diagnostics that came back."""
        v0, d0 = len(self.voltages), len(self.diagnostics)
        if preview is not None:
            self.preview_pub.publish(preview)
            self.h.spin_for(0.01)
        self.odom_pub.publish(odom)
        self.h.spin_until(lambda: len(self.diagnostics) > d0 and len(self.voltages) > v0, 2.0)
        self.h.spin_for(0.02)
        return [list(v.data) for v in self.voltages[v0:]], [_status(d) for d in self.diagnostics[d0:]]


@pytest.fixture(scope="module")
def harness():
    with Harness("hardening_test") as h:
        yield h


@pytest.fixture(scope="module")
def lockstep(harness, tmp_path_factory):
    rig = Rig(harness, "/hard")
    with NodeGroup(log_dir=tmp_path_factory.mktemp("hardening")) as group:
        rig.node = rig.start(group, {"mode": "lockstep"})
        yield rig


def test_a_stamp_that_is_no_time_is_refused_with_zero_volts(harness, lockstep):
    reason = "stamp"
    _, control = load_params()
    Ts_ns = round(control.period_s * 1e9)
    stamp = (300 + 10 * len(lockstep.voltages)) * Ts_ns  # a new tick
    preview = preview_message(make_reference("paper-circle"), stamp, control.period_s, control.horizon)
    odom = _odometry(stamp)
    odom.header.stamp.sec, odom.header.stamp.nanosec = 2**31 - 1, 2**32 - 1  # refused as future, then overflowed
    got_v, got_d = lockstep.tick(preview, odom)
    errors = [(s, kv) for s, kv in got_d if s.level == DiagnosticStatus.ERROR]
    assert got_v[:1] == [[0.0, 0.0, 0.0]] and errors, (got_v, got_d)
    status, kv = errors[-1]
    assert reason in status.message and kv["last_refusal"] == reason
    assert lockstep.node.popen.poll() is None, lockstep.node.stderr_tail()


def test_a_preview_in_another_frame_is_refused_naming_both_frames(harness, lockstep):
    """The controller (frame_prefix '') takes previews in 'odom' only: one in map gives its tick zero volts and
    an ERROR naming both frames.
    """
    frame = "map"
    _, control = load_params()
    stamp = (500 + 10 * len(lockstep.voltages)) * round(control.period_s * 1e9)
    preview = preview_message(make_reference("paper-circle"), stamp, control.period_s, control.horizon)
    preview.header.frame_id = frame
    got_v, got_d = lockstep.tick(preview, _odometry(stamp))
    errors = [(s, kv) for s, kv in got_d if s.level == DiagnosticStatus.ERROR]
    assert got_v[:1] == [[0.0, 0.0, 0.0]] and errors, (got_v, got_d)
    status, kv = errors[-1]
    assert kv["last_refusal"] == "preview_frame" and f"'{frame}'" in status.message and "'odom'" in status.message
    good = preview_message(make_reference("paper-circle"), stamp + 10**7, control.period_s, control.horizon)
    got_v, got_d = lockstep.tick(good, _odometry(stamp + 10**7))  # the same preview in 'odom' is tracked
    assert got_d[-1][0].message == "tracking" and got_v[-1] != [0.0, 0.0, 0.0], got_d


@pytest.mark.parametrize("values, words", [
    ({"odom_timeout_s": 0.005}, "two control periods"),
    ({"reference_timeout_s": 0.019}, "two control periods"),
    # one at a time (SetParameters): J = 100 is fine with l = 0.13 m, l = 1e-12 m then leaves T(theta) unbuildable
    ({"robot.yaw_inertia_kg_m2": 100.0, "robot.wheel_distance_m": 1e-12}, "dimension"),
])
def test_parameters_the_controller_cannot_run_on_are_refused(harness, lockstep, values, words):
    result = harness.set_parameters(f"hard/{NODE}", values)
    assert not result[-1].successful and words in result[-1].reason, result
    assert lockstep.node.popen.poll() is None, lockstep.node.stderr_tail()
    last = list(values)[-1]
    assert harness.get_parameters(f"hard/{NODE}", [last]) != [values[last]]


def _tracking(rig: Rig, stamp_of, clock=None, tries: int = 100) -> list:
    """Realtime: fresh preview and odometry (stamps from `stamp_of(k)`) until 3 ticks are tracked; their voltages."""
    _, control = load_params()
    reference = make_reference("paper-circle")
    answers = []
    for k in range(tries):
        stamp = stamp_of(k)
        if clock is not None:
            clock(stamp)
        preview = preview_message(reference, k * round(control.period_s * 1e9), control.period_s, control.horizon)
        preview.header.stamp = ns_to_stamp(stamp)
        got_v, got_d = rig.tick(preview, _odometry(stamp))
        if got_d and got_d[-1][0].message == "tracking":
            answers.append(got_v[-1])
            if len(answers) == 3:
                break
    return answers


def test_realtime_sim_time_going_back_resumes_tracking_after_the_watchdog(harness, tmp_path_factory):
    h, rig = harness, Rig(harness, "/simclock")
    clock_pub = h.node.create_publisher(Clock, "/clock", PUBLISH_QOS)

    def clock(stamp_ns):
        msg = Clock()
        msg.clock = ns_to_stamp(stamp_ns)
        clock_pub.publish(msg)
        h.spin_for(0.005)

    with NodeGroup(log_dir=tmp_path_factory.mktemp("simclock")) as group:
        node = rig.start(group, {"mode": "realtime", "use_sim_time": True, "odom_timeout_s": 0.2,
                                 "reference_timeout_s": 0.2})
        assert len(_tracking(rig, lambda k: 1000 * 10**9 + k * 10**7, clock)) == 3, node.stderr_tail()
        d0 = len(rig.diagnostics)
        h.spin_for(0.6)  # steady time without data but no simulated time: nothing is stale (the watchdog's clock)
        assert not any("watchdog: stale" in _status(d)[0].message for d in rig.diagnostics[d0:])
        for k in range(60):  # 0.6 s of simulated time without data: the watchdog declares the data stale
            clock(1000 * 10**9 + (100 + k) * 10**7)
        h.spin_for(0.1)
        assert any("watchdog: stale" in _status(d)[0].message for d in rig.diagnostics[d0:])
        # the clock restarts at 10 s: every input is older than the last used
        assert len(_tracking(rig, lambda k: 10 * 10**9 + k * 10**7, clock, tries=30)) == 3, [
            _status(d)[0].message for d in rig.diagnostics[d0:]][-5:]


def test_a_realtime_controller_stopped_by_sigint_leaves_zero_volts(harness, tmp_path_factory):
    h, rig = harness, Rig(harness, "/stopping")
    with NodeGroup(log_dir=tmp_path_factory.mktemp("stopping")) as group:
        node = rig.start(group, {"mode": "realtime", "odom_timeout_s": 5.0, "reference_timeout_s": 5.0})
        answers = _tracking(rig, lambda k: h.node.get_clock().now().nanoseconds)
        assert len(answers) == 3 and answers[-1] != [0.0, 0.0, 0.0], node.stderr_tail()
        count = len(rig.voltages)
        assert group.stop_node(node, 10.0) == 0, node.stderr_tail()
        h.spin_for(0.5)
        assert [list(v.data) for v in rig.voltages[count:]] == [[0.0, 0.0, 0.0]]  # within the 5 s timeout: no watchdog
