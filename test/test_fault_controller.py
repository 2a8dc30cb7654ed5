"""The realtime controller node under faults, in closed loop with a simulated Robotino.

* A loop closed by the test: a `RobotinoPlant` stepped in this process with the voltages the node sends,
  its odometry (stamped on an ideal 10 ms grid of the wall clock) and the paper-circle preview published
  by the test. A skipped, a late (+11 ms) and a duplicated odometry tick, and a live change of q_x, are
  compared with the same loop undisturbed.
* The real processes (plant, trajectory, controller, realtime): the controller, then the trajectory
  node, SIGKILLed mid paper-circle and restarted; the currents stay within the nominal current while the
  controller commands (a fail-safe stop on a late input brakes with back-EMF / R, bounded by it), and the
  robot converges back to the reference.
"""

import itertools
import math
import os
import signal

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import MultiDOFJointTrajectory

from harness import Harness
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.ros.messages import ns_to_stamp, preview_message, stamp_to_ns, yaw_to_quaternion
from robotino_geom_mpc.system.processes import NodeGroup, ros_args
from robotino_geom_mpc.ros.qos import PUBLISH_QOS
from robotino_geom_mpc.model.plant import RobotinoPlant

pytestmark = pytest.mark.ros

TICKS = 260
DISTURBANCES = {120: "skip", 160: "late", 200: "duplicate"}
CHANGE_AT = 150  # the tick before which q_x is set


def _values(diag):
    (status,) = diag.status
    return status, {kv.key: kv.value for kv in status.values}


def _odometry(stamp_ns, plant):
    """The plant's odometry message (pose in odom, twist in base_link), as the plant node sends it."""
    x, y, th = plant.pose
    vx, vy, w = plant.body_state[[1, 3, 5]].tolist()
    c, s = math.cos(th), math.sin(th)
    msg = Odometry()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation = yaw_to_quaternion(th)
    msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.angular.z = c * vx + s * vy, -s * vx + c * vy, w
    return msg


def _closed_loop(h, tmp_path, ns, disturbances=None, change=None):
    """Run TICKS ticks of the test-closed loop; returns (voltages per tick or None, diagnostics, the set result)."""
    robot, control = load_params()
    Ts_ns = round(control.period_s * 1e9)
    reference = make_reference("paper-circle")
    plant = RobotinoPlant(robot)
    voltages = h.collect(f"/{ns}/wheel_voltages", Float64MultiArray)
    diagnostics = h.collect(f"/{ns}/diagnostics", DiagnosticArray)
    odom_pub = h.node.create_publisher(Odometry, f"/{ns}/odom", PUBLISH_QOS)
    preview_pub = h.node.create_publisher(MultiDOFJointTrajectory, f"/{ns}/reference_preview", PUBLISH_QOS)
    answers, result = [], None
    with NodeGroup(log_dir=tmp_path / ns) as group:
        # long timeouts: this loop (a Python harness waiting for each answer on a shared machine) lags behind
        # its ideal 10 ms grid of stamps; the timeouts keep its stamps from going stale
        node = group.start("controller_node", [*ros_args(None, {
            "mode": "realtime", "odom_timeout_s": 30.0, "reference_timeout_s": 30.0}), "-r", f"__ns:=/{ns}"])
        assert h.spin_until(lambda: odom_pub.get_subscription_count() >= 1
                            and preview_pub.get_subscription_count() >= 1
                            and h.node.count_publishers(f"/{ns}/wheel_voltages") >= 1, 30.0), node.stderr_tail()
        h.spin_for(0.5)
        base = h.node.get_clock().now().nanoseconds
        U, late = np.zeros(3), None
        for k in range(TICKS):
            if change is not None and k == CHANGE_AT:
                (result,) = h.set_parameters(f"{ns}/robotino_controller", change)
            stamp = base + k * Ts_ns
            h.spin_until(lambda: h.node.get_clock().now().nanoseconds >= stamp, 1.0)
            preview_pub.publish(_restamped(preview_message(reference, k * Ts_ns, control.period_s,
                                                           control.horizon), stamp))
            kind = (disturbances or {}).get(k)
            count = len(voltages)
            if kind == "late":
                late = _odometry(stamp, plant)  # sent after the next tick's answer, 11 ms late
            elif kind != "skip":
                odom_pub.publish(_odometry(stamp, plant))
                if kind == "duplicate":
                    odom_pub.publish(_odometry(stamp, plant))
                assert h.spin_until(lambda: len(voltages) > count, 2.0), node.stderr_tail()
            answers.append(np.array(voltages[-1].data) if len(voltages) > count else None)
            if len(voltages) > count:
                U = np.array(voltages[-1].data)
            if late is not None and kind != "late":
                due = stamp_to_ns(late.header.stamp) + 11_000_000
                h.spin_until(lambda: h.node.get_clock().now().nanoseconds >= due, 1.0)
                odom_pub.publish(late)
                late = None
            h.spin_for(0.002)
            plant.step(U, control.period_s)
        h.spin_for(0.3)
        assert len(voltages) == sum(a is not None for a in answers), "an extra answer (to a dropped tick)"
    return answers, diagnostics, result


def _restamped(msg, stamp_ns):
    msg.header.stamp = ns_to_stamp(stamp_ns)
    return msg


@pytest.fixture(scope="module")
def harness():
    with Harness("fault_controller_test") as h:
        yield h


@pytest.fixture(scope="module")
def undisturbed(harness, tmp_path_factory):
    answers, diagnostics, _ = _closed_loop(harness, tmp_path_factory.mktemp("loop"), "undisturbed")
    assert all(a is not None for a in answers)
    return answers


def test_skipped_late_and_duplicated_odometry_move_no_voltage_by_more_than_a_volt(harness, undisturbed,
                                                                                   tmp_path_factory):
    answers, diagnostics, _ = _closed_loop(harness, tmp_path_factory.mktemp("loop"), "disturbed", DISTURBANCES)
    skipped = [k for k, a in enumerate(answers) if a is None]
    assert skipped == [120, 160]  # the skipped tick and the late one (older than the next when it came)
    both = [k for k in range(TICKS) if answers[k] is not None]
    deviation = max(np.abs(answers[k] - undisturbed[k]).max() for k in both)
    peak = max(np.abs(a).max() for a in answers if a is not None)
    print(f"\nskip/late/duplicate: largest voltage deviation from the undisturbed loop {deviation:.3f} V, "
          f"peak voltage {peak:.2f} V")
    assert deviation < 1.0 and peak < 24.0
    assert 0.01 < deviation  # the faults did change the loop (the comparison can fail)
    _, last = _values(diagnostics[-1])
    assert last["dropped_old"] == "1" and last["dropped_duplicate"] == "1" and last["rejected"] == "0"
    dts = {round(float(_values(d)[1]["dt_s"]), 6) for d in diagnostics if _values(d)[0].message == "tracking"}
    assert dts == {0.01, 0.02}  # the interval after the skipped and after the late tick: two periods


def test_a_stable_q_x_change_rebuilds_the_controller_without_a_voltage_step(harness, undisturbed, tmp_path_factory):
    answers, diagnostics, result = _closed_loop(harness, tmp_path_factory.mktemp("loop"), "qx",
                                                change={"control.q_x": 2.0e6})
    assert result.successful, result.reason
    steps = [np.abs(answers[k] - answers[k - 1]).max() for k in range(CHANGE_AT - 5, CHANGE_AT + 10)]
    usual = max(np.abs(undisturbed[k] - undisturbed[k - 1]).max() for k in range(CHANGE_AT - 5, CHANGE_AT + 10))
    print(f"\nq_x change: largest voltage step around it {max(steps):.3f} V (undisturbed loop: {usual:.3f} V)")
    assert max(steps) < 1.0
    assert max(np.abs(answers[k] - undisturbed[k]).max() for k in range(CHANGE_AT, TICKS)) > 1e-4  # it changed
    engagements = {_values(d)[1]["blend_engagements"] for d in diagnostics if _values(d)[0].message == "tracking"}
    assert engagements == {"1", "2"}  # the start and the rebuild


def _implied_voltages(joint, robot):
    """U = R i + Km gear omega_wheel per drive from joint_states (effort = gear Km i), L di/dt aside."""
    gear_km = robot.gear_ratio * robot.torque_constant_n_m_per_a
    return (robot.resistance_ohm * np.array(joint.effort) / gear_km
            + robot.torque_constant_n_m_per_a * robot.gear_ratio * np.array(joint.velocity))


def _status_runs(diagnostics: list) -> str:
    """The last dozen runs of equal status messages: 'message xcount first..last stamp'."""
    runs = [(message, [stamp for stamp, _ in group]) for message, group in itertools.groupby(
        ((stamp_to_ns(d.header.stamp), _values(d)[0].message) for d in diagnostics), key=lambda sm: sm[1])]
    return "; ".join(f"{message} x{len(stamps)} {stamps[0]}..{stamps[-1]}" for message, stamps in runs[-12:])


def _around_peak(joints: list, statuses: list, gear_km: float, t0: int, window_ns: int = 50_000_000) -> str:
    """The plant's currents and the controller's statuses within `window_ns` of the highest current in `joints`
    (times in s after `t0`): what a failing current bound shows.
    """
    peak = max(joints, key=lambda j: np.abs(j.effort).max())
    at = stamp_to_ns(peak.header.stamp)
    near = [f"{(stamp_to_ns(j.header.stamp) - t0) * 1e-9:.3f} s: {np.round(np.asarray(j.effort) / gear_km, 3)} A"
            for j in joints if abs(stamp_to_ns(j.header.stamp) - at) <= window_ns]
    keys = ("dt_s", "saturated", "watchdog", "blend_remaining_s")
    said = [f"{(stamp - t0) * 1e-9:.3f} s: {message} {({k: kv[k] for k in keys if k in kv})}"
            for stamp, message, kv in statuses if abs(stamp - at) <= window_ns]
    return "currents " + "; ".join(near) + " | statuses " + "; ".join(said)


def _fail_safe_episodes(statuses: list, period_s: float, command_timeout_s: float) -> list:
    """(start, end, blend_s) of each stretch of zero volts in `statuses` ((stamp, message, values) of the
    controller's diagnostics, in order): a zero-volt status (watchdog, refused input, disabled) until the next
    answer, or a gap in the answers longer than the plant's command timeout (its drive watchdog); `blend_s` is the
    restart blend after it. A dropped input (stamped as that input, no answer) is neither.
    """
    gap_ns = (command_timeout_s - period_s) * 1e9
    answers = [status for status in statuses if not status[1].startswith("dropped")]
    return [(s0, s1, float(kv1["blend_remaining_s"]) if m1 == "tracking" else 0.0)
            for (s0, m0, _), (s1, m1, kv1) in itertools.pairwise(answers) if m0 != "tracking" or s1 - s0 > gap_ns]


def _within(stamp, windows):
    """Whether `stamp` [ns] falls in one of the (start, end) `windows` [ns]."""
    return any(start <= stamp <= end for start, end in windows)


def _reblends(episodes):
    """(start, end) of each fail-safe stop until 2 s after its restart blend [ns]."""
    return [(start, end + (blend + 2.0) * 1e9) for start, end, blend in episodes]


def _kill_and_restart(h, tmp_path, ns, victim):
    """Plant, trajectory and controller in realtime on paper-circle; `victim` SIGKILLed after 5 s of tracking,
    restarted 1 s later. Returns what the test checks.
    """
    robot, control = load_params()
    currents = h.collect(f"/{ns}/wheel_currents", Float64MultiArray)
    joints = h.collect(f"/{ns}/joint_states", JointState)
    diagnostics = h.collect(f"/{ns}/diagnostics", DiagnosticArray)
    remap = ["-r", f"__ns:=/{ns}"]
    args = {"plant_node": ros_args(None, {"mode": "realtime"}) + remap,
            "trajectory_node": ros_args(None, {"mode": "realtime", "scenario": "paper-circle"}) + remap,
            "controller_node": ros_args(None, {"mode": "realtime"}) + remap}
    command_timeout_s = 0.1  # the plant's default

    statuses = []  # (stamp, message, values) of each diagnostic, parsed once: the waits ask after every message

    def parse() -> list:
        statuses.extend((stamp_to_ns(d.header.stamp), status.message, kv)
                        for d in diagnostics[len(statuses):] for status, kv in [_values(d)])
        return statuses

    def tracking(since_ns=0):
        return [(stamp, kv) for stamp, message, kv in parse() if message == "tracking" and stamp > since_ns]

    def settled(t0, T):
        """Tracking 3 s past the blend and 2 s past the restart blend of any later fail-safe stop."""
        after = [s for s in parse() if s[0] >= t0]
        reblends = _reblends(_fail_safe_episodes(after, control.period_s, command_timeout_s))
        return after[-1][0] > max([t0 + (T + 3.0) * 1e9] + [end for _, end in reblends])

    with NodeGroup(log_dir=tmp_path / "first") as group, NodeGroup(log_dir=tmp_path / "second") as second:
        nodes = {name: group.start(name, a) for name, a in args.items()}
        assert h.spin_until(lambda: len(tracking()) > 0, 60.0), nodes["controller_node"].stderr_tail()
        first = tracking()[0][0]
        assert h.spin_until(lambda: tracking()[-1][0] - first > 5e9, 30.0)
        os.killpg(nodes[victim].popen.pid, signal.SIGKILL)
        kill_ns = h.node.get_clock().now().nanoseconds
        nodes[victim].popen.wait()
        h.spin_for(1.0)
        restart_ns = h.node.get_clock().now().nanoseconds
        # the currents carry no stamp: counted from the first joint state after the restart (a loaded host's
        # harness lags the plant, and the braking after the kill, before the restart, was counted as after it)
        assert h.spin_until(lambda: joints and stamp_to_ns(joints[-1].header.stamp) > restart_ns, 10.0)
        current_start = len(currents)
        restarted = second.start(victim, args[victim])
        assert h.spin_until(lambda: len(tracking(restart_ns)) > 0, 60.0), restarted.stderr_tail()
        t0, kv = tracking(restart_ns)[0]
        T = float(kv["blend_remaining_s"])
        if not h.spin_until(lambda: settled(t0, T), 60.0):
            exits = {name: n.popen.poll() for name, n in [*nodes.items(), ("restarted", restarted)]}
            raise AssertionError(f"tracking stopped (t0 {t0} ns, T {T} s, exit codes {exits}): "
                                 f"{_status_runs(diagnostics)}\n{nodes['controller_node'].stderr_tail()}\n"
                                 f"{restarted.stderr_tail()}")
        assert all(n.popen.poll() is None for n in [*nodes.values(), restarted] if n is not nodes[victim])
    plant_log = nodes["plant_node"].stderr_tail(200)  # complete: the group has stopped the nodes
    zero = [stamp_to_ns(j.header.stamp) for j in joints if stamp_to_ns(j.header.stamp) > kill_ns
            and np.abs(_implied_voltages(j, robot)).max() < 0.5]
    episodes = _fail_safe_episodes([s for s in parse() if s[0] >= t0], control.period_s, command_timeout_s)
    errors = [(stamp, math.hypot(float(kv["error_x_m"]), float(kv["error_y_m"]))) for stamp, kv in tracking(t0)]
    after = [j for j in joints if stamp_to_ns(j.header.stamp) > restart_ns]
    return dict(robot=robot, period_s=control.period_s, kill_to_zero_s=(zero[0] - kill_ns) * 1e-9 if zero else None,
                T=T, t0=t0, peak_after=max(np.abs(c.data).max() for c in currents[current_start:]),
                joints_after=after, statuses=statuses, episodes=episodes, plant_log=plant_log, errors=errors)


@pytest.mark.slow
@pytest.mark.parametrize("victim", ["controller_node", "trajectory_node"])
def test_a_node_killed_and_restarted_mid_circle_restarts_bumplessly(harness, tmp_path_factory, victim):
    """The limit holds while the controller commands. A late input on a loaded host (0.1 s) stops the drives
    (zero volts, the fail-safe), and a wheel turning at speed then brakes with its back-EMF over R, above the
    limit: bounded by that physics, and each such stop restarts the tracking with a blend of its own.

    The commanded ticks keep the nominal current plus 2 % (the issue's tolerance): the limit holds by
    construction for a voltage held one period, but in real time a command that comes late, short of a stop,
    is held longer while the back-EMF moves on. One full-suite run had fail-safe stops of 10, 10 and 301 ms
    right after the restart (a stalled host) and 0.866 A at a commanded tick for a nominal 0.86 A, most
    likely so (not reproduced in seven runs since, four of them beside a busy core); a later one had 0.892 A
    and no stop (not reproduced in 14 runs beside two busy loops). A failing bound shows the ticks around its peak.
    """
    out = _kill_and_restart(harness, tmp_path_factory.mktemp("kill"), f"kill_{victim.split('_')[0]}", victim)
    robot, episodes = out["robot"], out["episodes"]
    gear_km = robot.gear_ratio * robot.torque_constant_n_m_per_a
    stops = [(start, end + 2 * out["period_s"] * 1e9) for start, end, _ in episodes]
    commanded_joints = [j for j in out["joints_after"] if not _within(stamp_to_ns(j.header.stamp), stops)]
    commanded = [np.abs(j.effort).max() / gear_km for j in commanded_joints]
    braking = gear_km * max(np.abs(j.velocity).max() for j in out["joints_after"]) / robot.resistance_ohm
    converged = [e for stamp, e in out["errors"] if stamp > out["t0"] + (out["T"] + 2.0) * 1e9
                 and not _within(stamp, _reblends(episodes))]
    print(f"\n{victim} SIGKILLed: zero volts at the plant {out['kill_to_zero_s']} s after the kill; after the restart "
          f"a blend of {out['T']:.2f} s, peak current {out['peak_after']:.3f} A ({max(commanded):.3f} A at the ticks "
          f"the controller commanded), error {out['errors'][0][1] * 1e3:.1f} mm -> "
          f"{max(converged, default=math.nan) * 1e3:.3f} mm from T + 2 s on; fail-safe stops (s after the restart, "
          f"s long) {[((s - out['t0']) * 1e-9, (e - s) * 1e-9) for s, e, _ in episodes]}"
          f" (braking bound {braking:.3f} A)")
    assert max(commanded) <= 1.02 * robot.nominal_current_a, _around_peak(commanded_joints, out["statuses"], gear_km,
                                                                          out["t0"])
    # the period peaks: within the nominal current unless a fail-safe stop braked the wheels
    assert out["peak_after"] <= (max(robot.nominal_current_a, 1.02 * braking) if episodes else robot.nominal_current_a)
    # realtime on a shared host: a late tick can put one tick's error above a millimetre. Converged: 95 % of the
    # ticks from T + 2 s on below 1 mm, and none above 1 cm (no divergence)
    assert converged and np.percentile(converged, 95) < 1e-3 and max(converged) < 1e-2
    assert out["errors"][0][1] > 0.01  # the restart found the robot off the reference (the test can fail)
    if victim == "controller_node":
        assert out["kill_to_zero_s"] is not None  # the plant's command timeout stopped the drives
        assert "no command for 0.1 s: zero volts (drive watchdog; 1 so far)" in out["plant_log"]
