"""The realtime controller process killed and restarted, in closed loop with the simulated Robotino.

The real processes (plant, trajectory, controller, realtime): the controller SIGKILLed mid paper-circle and
restarted 1 s later; the plant's drive watchdog stops the drives, the currents stay within the nominal current
while the controller commands (a fail-safe stop on a late input brakes with back-EMF / R, bounded by it), and the
robot converges back to the reference.

The tick's cases run in-process (test_controller_loop_cases): a skipped, a late and a duplicated odometry against
the undisturbed loop, a live q_x change, and the trajectory restarted (its previews gone for a second, then a
reference from t = 0: the watchdog's zero, a bumpless restart that converges), which was this file's
``trajectory_node`` kill: over DDS it added a restarted trajectory node finding the controller and the odometry
again (its start: test_trajectory_node) and the controller's subscription taking the new publisher's messages.
"""

import itertools
import math
import os
import signal

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from harness import Harness
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.messages import stamp_to_ns
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

pytestmark = pytest.mark.ros

def _values(diag):
    (status,) = diag.status
    return status, {kv.key: kv.value for kv in status.values}


@pytest.fixture(scope="module")
def harness():
    with Harness("fault_controller_test") as h:
        yield h


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
def test_the_controller_killed_and_restarted_mid_circle_restarts_bumplessly(harness, tmp_path_factory):
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
    victim = "controller_node"
    out = _kill_and_restart(harness, tmp_path_factory.mktemp("kill"), "kill_controller", victim)
    robot, episodes = out["robot"], out["episodes"]
    gear_km = robot.gear_ratio * robot.torque_constant_n_m_per_a
    stops = [(start, end + 2 * out["period_s"] * 1e9) for start, end, _ in episodes]
    # the restarted controller's ticks: from its first answer on (before it, the plant's own zero volts of the
    # drive watchdog: a CI run's plant stalled 2.8 s at the kill, and braked at 1.04 A 0.86 s before t0)
    commanded_joints = [j for j in out["joints_after"] if stamp_to_ns(j.header.stamp) >= out["t0"]
                        and not _within(stamp_to_ns(j.header.stamp), stops)]
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
    assert out["kill_to_zero_s"] is not None  # the plant's command timeout stopped the drives
    assert "no command for 0.1 s: zero volts (drive watchdog; 1 so far)" in out["plant_log"]
