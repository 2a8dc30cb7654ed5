"""``start_enabled: false`` on the controller: zero output and the diagnostic ``disabled`` until ``~/enable`` true,
then a bumpless start (issue 36, item 3).

Lockstep (voltages): as test/test_enable_service.py, the real plant and controller processes of a lockstep
paper-circle in which the test is the trajectory (one preview per /clock tick) and enables the controller before
the preview of tick `ENABLE_TICK`: the disabled ticks are exactly 0 .. ENABLE_TICK - 1 whatever the host's load.
The truth is the loop probe's (ground truth, the plant's currents, the controller's voltages per tick).

Realtime through the driver chain (cmd_vel, ``chain.active``): the emulated chain plant, the chain controller and
the trajectory node; the test's own subscriptions (cmd_vel, diagnostics, ground truth, reference previews, the
plant's currents) are the truth. Twice: the reference running from the launch on (the controller catches up at
the enable), and started by the enable from where the robot stands (the trajectory's ``start_on_enable`` and
``anchor_to_robot``, as launch/real_robot.launch.py runs it), the robot driven off the origin and turned first.
"""

import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry, Path
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool
from trajectory_msgs.msg import MultiDOFJointTrajectory

from harness import Harness
from probe import PROBE_WAIT_FOR, ProbeSpinner
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.ros.decode import unwrap_near
from robotino_geom_mpc.ros.messages import preview_message, quaternion_to_yaw, stamp_to_ns
from robotino_geom_mpc.ros.qos import CLOCK_SUB_QOS, LATCHED_QOS, publish_qos
from robotino_geom_mpc.scenarios import SCENARIOS
from robotino_geom_mpc.system.processes import NodeGroup, node_arguments

pytestmark = pytest.mark.ros

DURATION_S = 10.0
ENABLE_TICK = 200  # held 2 s from the start: the reference (at rest at t = 0) is 0.31 m along the circle by then


@pytest.mark.slow
def test_a_lockstep_controller_started_disabled_sends_zero_volts_until_enabled_then_starts_bumplessly(tmp_path):
    robot, control = load_params()
    period_ns, ticks = round(control.period_s * 1e9), round(DURATION_S / control.period_s)
    reference = SCENARIOS["paper-circle"].make_reference()
    probe = ProbeSpinner()
    try:
        with Harness("start_disabled_probe") as h, NodeGroup(log_dir=tmp_path) as group:
            diagnostics = h.collect("diagnostics", DiagnosticArray)
            clock = set()
            h.node.create_subscription(Clock, "/clock", lambda m: clock.add(stamp_to_ns(m.clock)), CLOCK_SUB_QOS)
            preview = h.node.create_publisher(MultiDOFJointTrajectory, "reference_preview", publish_qos(True))
            args = node_arguments("paper-circle", default_params_file(), DURATION_S, True,
                                  wait_for=[*PROBE_WAIT_FOR, "diagnostics:1"],
                                  overrides={"controller_node": {"start_enabled": False}})
            plant = group.start("plant_node", args["plant_node"])
            controller = group.start("controller_node", args["controller_node"])
            client = h.node.create_client(SetBool, "/robotino_controller/enable")
            assert client.wait_for_service(timeout_sec=60.0)
            assert h.spin_until(lambda: preview.get_subscription_count() >= 2, 120.0), plant.stderr_tail()
            for k in range(ticks):
                assert h.spin_until(lambda: k * period_ns in clock, 240.0), (k, plant.stderr_tail())
                if k == ENABLE_TICK:
                    assert h._call(client, SetBool.Request(data=True), 30.0).message == "enabled"
                preview.publish(preview_message(reference, k * period_ns, control.period_s, control.horizon))
            assert h.spin_until(lambda: plant.popen.poll() is not None, 240.0), plant.stderr_tail()
            assert plant.popen.returncode == 0
            h.spin_for(0.3)
            controller_log = controller.stderr_tail(30)
        deadline = time.monotonic() + 120.0  # the probe (another thread) may lag behind: let it take every sample
        while min(len(probe.probe.truth), len(probe.probe.currents), len(probe.probe.voltages)) < ticks and \
                time.monotonic() < deadline:
            time.sleep(0.1)
        run = probe.probe.run_data("paper-circle")
    finally:
        probe.close()
    assert "disabled (zero output) until /robotino_controller/enable true" in controller_log
    messages = {}
    for msg in diagnostics:
        messages.setdefault(stamp_to_ns(msg.header.stamp), []).append(msg.status[0].message)
    disabled = sorted(s // period_ns for s, m in messages.items() if "disabled" in m)
    assert run.n == ticks
    held = list(range(ENABLE_TICK))
    assert disabled == held  # every tick from the first until the enable, and none after
    assert np.all(run.voltages[held] == 0.0)
    assert np.all(run.pose[held] == 0.0)  # at zero volts from rest the robot never moved
    error = np.hypot(*(run.pose[:, :2] - run.reference[:, :2]).T)
    assert error[ENABLE_TICK] > 0.25  # the reference had gone on without it
    # enabled: the reference blended in from the robot at rest; the currents stay within the limit, below nominal,
    # and the error ends at the micrometres a run started enabled has (simulate: ~2 um)
    peak = np.abs(run.currents[ENABLE_TICK:]).max()
    assert peak <= 1.02 * control.current_limit_a and peak < robot.nominal_current_a, peak
    tail = error[-round(1.0 / control.period_s):]
    assert tail.max() < 1e-5, tail.max()
    print(f"error at enable {error[ENABLE_TICK]:.4f} m, peak current after {peak:.4f} A (nominal "
          f"{robot.nominal_current_a:g} A), error over the last second max {tail.max():.3g} m")


CHAIN = {"command_interface": "cmd_vel", "chain.active": "enabled"}
HOLD_S = 2.0  # disabled this long after the reference started to move
TRACK_S = 12.0  # then enabled


def _preview_point(msg: MultiDOFJointTrajectory) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(stamp, position, velocity, acceleration) of a preview's point 0, x y theta."""
    point = msg.points[0]
    tf, v, a = point.transforms[0], point.velocities[0], point.accelerations[0]
    position = np.array([tf.translation.x, tf.translation.y, quaternion_to_yaw(tf.rotation)])
    return (stamp_to_ns(msg.header.stamp), position, np.array([v.linear.x, v.linear.y, v.angular.z]),
            np.array([a.linear.x, a.linear.y, a.angular.z]))


def _reference_at(previews: list, stamp: int) -> np.ndarray | None:
    """The reference at `stamp` from the newest preview stamped before it (second order), None before the first."""
    before = [p for p in previews if p[0] <= stamp]
    if not before:
        return None
    s, p, v, a = before[-1]
    dt = (stamp - s) * 1e-9
    return p + v * dt + 0.5 * a * dt * dt


@pytest.mark.slow
def test_through_the_driver_chain_a_controller_started_disabled_sends_zero_twists_until_enabled(tmp_path):
    robot, control = load_params()
    args = node_arguments("paper-circle", default_params_file(), 0.0, False, command_interface="cmd_vel",
                          overrides={"plant_node": {**CHAIN, "wheel_pi.rate_hz": 200.0},
                                     "controller_node": {**CHAIN, "start_enabled": False}})
    with Harness("start_disabled_chain") as h, NodeGroup(log_dir=tmp_path) as group:
        twists, diagnostics, currents = [], [], []
        h.node.create_subscription(Twist, "cmd_vel", lambda m: twists.append(
            (time.monotonic(), (m.linear.x, m.linear.y, m.angular.z))), 100)
        h.node.create_subscription(DiagnosticArray, "diagnostics", lambda m: diagnostics.append(
            (time.monotonic(), m.status[0].message)), 100)
        h.node.create_subscription(Float64MultiArray, "wheel_currents", lambda m: currents.append(
            (time.monotonic(), list(m.data))), 100)
        truth, previews, theta = [], [], [0.0]

        def on_truth(msg: Odometry) -> None:
            theta[0] = unwrap_near(quaternion_to_yaw(msg.pose.pose.orientation), theta[0])
            truth.append((time.monotonic(), stamp_to_ns(msg.header.stamp), np.array(
                [msg.pose.pose.position.x, msg.pose.pose.position.y, theta[0]])))
        h.node.create_subscription(Odometry, "ground_truth/odom", on_truth, 100)
        h.node.create_subscription(MultiDOFJointTrajectory, "reference_preview",
                                   lambda m: previews.append(_preview_point(m)), 100)
        plant = group.start("plant_node", args["plant_node"])
        group.start("controller_node", args["controller_node"])
        group.start("trajectory_node", args["trajectory_node"])
        client = h.node.create_client(SetBool, "/robotino_controller/enable")
        assert client.wait_for_service(timeout_sec=60.0)
        # the reference starts (the trajectory's start_settle_s after the controller subscribed) and moves on
        assert h.spin_until(lambda: previews and np.abs(previews[-1][2]).max() > 0.0, 120.0), plant.stderr_tail()
        h.spin_for(HOLD_S)
        enabled_at = time.monotonic()
        assert h._call(client, SetBool.Request(data=True), 30.0).message == "enabled"
        h.spin_for(TRACK_S)
        assert plant.popen.poll() is None, plant.stderr_tail()
    held = [t for at, t in twists if at < enabled_at]
    assert len(held) > HOLD_S * 20  # every odometry answered (the driver dispatches at 30 Hz)
    assert all(t == (0.0, 0.0, 0.0) for t in held)
    before_enable = {m for at, m in diagnostics if at < enabled_at}  # (the watchdog's on a late odometry: zero too)
    assert "disabled" in before_enable and all(m == "disabled" or m.startswith("watchdog") for m in before_enable)
    assert "disabled" not in {m for at, m in diagnostics if at > enabled_at + 0.5}
    assert any(max(map(abs, t)) > 0.05 for at, t in twists if at > enabled_at)  # it drives
    assert np.abs(np.array([p for at, s, p in truth if at < enabled_at])).max() < 1e-9  # it never left its start
    errors = [(s, np.hypot(*(p - r)[:2])) for at, s, p in truth if (r := _reference_at(previews, s)) is not None]
    start = next(s for at, s, p in truth if np.abs(p).max() > 1e-6)  # its first motion after the enable
    before = max(e for s, e in errors if s <= start)
    tail = np.array([e for s, e in errors if s > errors[-1][0] - 4e9])  # the last 4 s
    peak = max(np.abs(c).max() for at, c in currents if at > enabled_at)
    print(f"error at enable {before:.3f} m, last 4 s: rms {np.sqrt(np.mean(tail**2)) * 1e3:.2f} mm, max "
          f"{tail.max() * 1e3:.2f} mm; peak current after the enable {peak:.3f} A (nominal "
          f"{robot.nominal_current_a:g} A)")
    assert before > 0.2  # the reference had gone on without it
    # back on the circle within the chain's figures (started enabled: 0.9 mm over DDS; offline rms <= 2 mm), within
    # the ramps: no current beyond nominal
    assert np.sqrt(np.mean(tail**2)) < 0.005 and tail.max() < 0.01
    assert peak < robot.nominal_current_a


WALK = ((0.15, 0.1, 0.4), 2.0)  # a body twist [m/s, m/s, rad/s] held this long [s]: the robot off the origin, turned
STANDS_S = 3.0  # held disabled this long with the reference holding at the robot, before the enable


def _moved(rows: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(x, y, theta) rows moved rigidly onto `pose` (complex numbers: z' = z0 + e^{i theta0} z)."""
    z = (pose[0] + 1j * pose[1]) + np.exp(1j * pose[2]) * (rows[:, 0] + 1j * rows[:, 1])
    return np.column_stack((z.real, z.imag, rows[:, 2] + pose[2]))


@pytest.mark.slow
def test_through_the_driver_chain_the_reference_starts_at_the_enable_from_where_the_robot_stands(tmp_path):
    """``start_on_enable`` and ``anchor_to_robot`` on the trajectory (as real_robot.launch.py sets them): the robot,
    driven off the origin and turned first (as identify leaves it), is held disabled while the reference holds its
    start at the robot; enabled, it runs the whole paper-circle from where it stands, the error within a few mm
    from the enable on (the reference running from the launch on: 0.35 m behind at the enable, ~5 s to catch up).
    The truth: the plant's ground truth against paper-circle moved rigidly onto the truth's pose at the enable,
    at the time since t = 0 (the reference_path's stamp).
    """
    robot, control = load_params()
    circle = SCENARIOS["paper-circle"].make_reference()
    args = node_arguments("paper-circle", default_params_file(), 0.0, False, command_interface="cmd_vel",
                          overrides={"plant_node": {**CHAIN, "wheel_pi.rate_hz": 200.0},
                                     "controller_node": {**CHAIN, "start_enabled": False},
                                     "trajectory_node": {"start_on_enable": True, "anchor_to_robot": True}})
    with Harness("start_on_enable_chain") as h, NodeGroup(log_dir=tmp_path) as group:
        twists, currents, truth, previews = [], [], [], []
        h.node.create_subscription(Twist, "cmd_vel", lambda m: twists.append(
            (time.time(), (m.linear.x, m.linear.y, m.angular.z))), 100)
        h.node.create_subscription(Float64MultiArray, "wheel_currents", lambda m: currents.append(
            (time.time(), list(m.data))), 100)
        theta = [0.0]

        def on_truth(msg: Odometry) -> None:
            theta[0] = unwrap_near(quaternion_to_yaw(msg.pose.pose.orientation), theta[0])
            truth.append((time.time(), stamp_to_ns(msg.header.stamp), np.array(
                [msg.pose.pose.position.x, msg.pose.pose.position.y, theta[0]])))
        h.node.create_subscription(Odometry, "ground_truth/odom", on_truth, 100)
        h.node.create_subscription(MultiDOFJointTrajectory, "reference_preview", lambda m: previews.append(
            (time.time(), _preview_point(m))), 100)
        paths = h.collect("reference_path", Path, LATCHED_QOS)
        plant = group.start("plant_node", args["plant_node"])
        # the test drives the robot off the origin first, as identify would (the chain's cmd_vel, 30 Hz)
        walk = h.node.create_publisher(Twist, "cmd_vel", 10)
        assert h.spin_until(lambda: walk.get_subscription_count() >= 1 and truth, 120.0), plant.stderr_tail()
        for k in range(round(WALK[1] * 30) + 30):
            twist = Twist()
            if k < WALK[1] * 30:
                twist.linear.x, twist.linear.y, twist.angular.z = WALK[0]
            walk.publish(twist)
            h.spin_for(1 / 30)
        h.node.destroy_publisher(walk)
        assert h.spin_until(lambda: np.abs(truth[-1][2] - truth[-10][2]).max() < 1e-9, 30.0)  # at rest
        controller_at = time.time()  # the twists after it are the controller's
        group.start("controller_node", args["controller_node"])
        trajectory = group.start("trajectory_node", args["trajectory_node"])
        client = h.node.create_client(SetBool, "/robotino_controller/enable")
        assert client.wait_for_service(timeout_sec=60.0)
        assert h.spin_until(lambda: len(previews) > 20, 120.0), trajectory.stderr_tail()  # holding
        h.spin_for(STANDS_S)
        stands = truth[-1][2]
        enabled_at = time.time()
        assert h._call(client, SetBool.Request(data=True), 30.0).message == "enabled"
        answered_at = time.time()
        assert h.spin_until(lambda: paths, 30.0), trajectory.stderr_tail()
        h.spin_for(circle.duration_s + 1.0)
        assert plant.popen.poll() is None, plant.stderr_tail()
    t0 = stamp_to_ns(paths[0].header.stamp)  # t = 0 of the reference
    print(f"robot off the origin at ({stands[0]:.3f} m, {stands[1]:.3f} m, {stands[2]:.3f} rad); t = 0 "
          f"{t0 * 1e-9 - enabled_at:.4f} s after the enable was called (answered after "
          f"{answered_at - enabled_at:.4f} s)")
    assert np.hypot(*stands[:2]) > 0.3 and abs(stands[2]) > 0.5  # off the origin, turned
    assert t0 * 1e-9 >= enabled_at  # started by the enable ...
    held = [p for at, (s, p, v, a) in previews if s < t0]
    assert len(held) > STANDS_S / control.period_s  # ... held before it, at the robot's pose, at rest
    assert np.abs(np.array(held) - stands).max() < 1e-6
    assert all(not v.any() and not a.any() for at, (s, p, v, a) in previews if s < t0)
    ours = [(at, t) for at, t in twists if at > controller_at]
    assert any(at < enabled_at for at, t in ours)  # zero twists while disabled ...
    assert all(at >= enabled_at for at, t in ours if max(map(abs, t)) > 0.0)  # ... and a move only after the enable
    # from the enable on: the truth against paper-circle moved onto where the robot stood, at its time since t = 0
    after = [(s, p) for at, s, p in truth if at > enabled_at and s >= t0]
    stamps = np.array([s for s, _ in after])
    reference = _moved(circle.position((stamps - t0) * 1e-9), stands)
    errors = np.hypot(*(np.array([p for _, p in after])[:, :2] - reference[:, :2]).T)
    heading = np.abs(np.array([p[2] for _, p in after]) - stands[2])
    centre = stands[:2] + circle.radius_m * np.array([-np.sin(stands[2]), np.cos(stands[2])])
    radius = np.hypot(*(np.array([p[:2] for _, p in after]) - centre).T)
    peak = max(np.abs(c).max() for at, c in currents if at > enabled_at)
    print(f"from the enable on ({(stamps[-1] - stamps[0]) * 1e-9:.1f} s, {len(errors)} samples): error max "
          f"{errors.max() * 1e3:.2f} mm, rms {np.sqrt(np.mean(errors ** 2)) * 1e3:.2f} mm, first second max "
          f"{errors[stamps < stamps[0] + 1e9].max() * 1e3:.2f} mm; heading max {heading.max() * 1e3:.2f} mrad; "
          f"radius about the anchored centre {radius.min():.4f}-{radius.max():.4f} m; end "
          f"{np.hypot(*(after[-1][1][:2] - stands[:2])) * 1e3:.2f} mm from the start; peak current {peak:.3f} A "
          f"(nominal {robot.nominal_current_a:g} A)")
    assert (stamps[-1] - t0) * 1e-9 > circle.duration_s  # the whole circle
    assert errors.max() < 0.006 and np.sqrt(np.mean(errors ** 2)) < 0.003
    assert heading.max() < 0.02
    assert np.abs(radius - circle.radius_m).max() < 0.006 and np.ptp(radius) < 0.012  # around the anchored centre
    assert np.hypot(*(after[-1][1][:2] - stands[:2])) < 0.003  # and ends where it started
    assert peak < robot.nominal_current_a
