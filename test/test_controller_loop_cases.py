"""The controller's tick in closed loop, in-process, with a hand-driven clock: the cases the DDS tests ran.

Each case runs `loop.controller_loop.ControllerLoop` against a robot stepped here (`RobotinoPlant` through a
`RobotLoop`, or the emulated driver chain through a `ChainRobot`), fed as the nodes feed it, on a clock this file
advances. The truths: the plant's own pose and currents against the reference (sampled here, or moved rigidly by
complex numbers, independent of `reference.anchor`), the same run without the fault, and a `MotionController`
stepped directly with the blend of `ReferenceBlend` at the measured state.

* lockstep (was test_start_disabled, test_enable_service over DDS): started disabled, enabled; disabled
  mid-circle and enabled again: zero volts and the status ``disabled`` on exactly the disabled ticks, then a
  bumpless start within the current limit, back at micrometres;
* realtime (was test_fault_controller): a skipped, a late and a duplicated odometry against the undisturbed loop;
  a live q_x change rebuilding the controller without a voltage step; the trajectory restarted (its previews gone
  for a second, then a reference from t = 0): zero, then a bumpless restart that converges;
* lockstep under ``use_sim_time`` (was test_sim_time_watchdog): with the node clock as the watchdog's, a slow
  loop is never stale; with steady time it is;
* through the driver chain (was test_start_disabled): started disabled, zero twists until the enable, then the
  catch-up; and the reference started at the enable from where the robot stands (``start_on_enable``,
  ``anchor_to_robot``): the whole anchored circle, back where it started.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from robotino_geom_mpc.control.blend import ANGULAR_LIMIT_RADPS2, LINEAR_LIMIT_MPS2, ReferenceBlend
from robotino_geom_mpc.control.motion_controller import MotionController, states_from_odometry
from robotino_geom_mpc.loop.chain_robot import ChainRobot
from robotino_geom_mpc.loop.controller_loop import ControllerLoop, LoopSettings
from robotino_geom_mpc.loop.events import Command, Diagnostic, Now, Preview, Zero
from robotino_geom_mpc.loop.robot_loop import PoseNoise, RobotLoop, VoltageDrive
from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import chain_params
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.offline.lockstep import PreviewRows, odometry_event
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.anchor import anchored
from robotino_geom_mpc.reference.trajectories import Reference
from robotino_geom_mpc.scenarios import SCENARIOS

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params()
TS = CONTROL.period_s
TS_NS = round(TS * 1e9)
N = CONTROL.horizon
CIRCLE = SCENARIOS["paper-circle"].make_reference()
MS = 1_000_000
T0_NS = 1_000 * 10**9  # the realtime runs' clock at their start (any time after 0)


def _commands(outputs) -> list[Command]:
    return [o for o in outputs if isinstance(o, Command)]


def _statuses(outputs) -> list[Diagnostic]:
    return [o for o in outputs if isinstance(o, Diagnostic)]


def _preview(reference: Reference, t_s: float, stamp_ns: int, points: int = N + 1) -> Preview:
    """The trajectory node's preview of `reference` at its time `t_s`, stamped `stamp_ns` (yaw as a quaternion)."""
    pos, vel, acc, _ = reference.sample(t_s + TS * np.arange(points))
    values: list[float] = []
    for p, v, a in zip(pos.tolist(), vel.tolist(), acc.tolist()):
        values += (p[0], p[1], 0.0, 0.0, math.sin(p[2] / 2), math.cos(p[2] / 2), *v, *a)
    return Preview(stamp_ns, "odom", tuple(values))


def _hold_preview(pose, stamp_ns: int) -> Preview:
    """The trajectory node's hold (``start_on_enable`` before the enable): every point at `pose`, at rest."""
    x, y, theta = pose
    point = (x, y, 0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2), *(0.0,) * 6)
    return Preview(stamp_ns, "odom", point * (N + 1))


def _robot() -> RobotLoop:
    plant = RobotinoPlant(ROBOT)
    return RobotLoop(plant, plant, VoltageDrive(plant), TS, PoseNoise((0.0, 0.0), 0))


# lockstep: disabled, enabled ---------------------------------------------------------------------------------
def _lockstep_run(ticks: int, switches: dict[int, bool], enabled: bool) -> dict:
    """paper-circle in lockstep as the plant, trajectory and controller nodes run it: tick k's preview, then its
    odometry; ``~/enable`` called before tick k's preview for each k in `switches`. Per tick: the true pose, the
    reference, the voltages applied, the peak |current| over the period, the statuses' messages, the state.
    """
    loop = ControllerLoop(ROBOT, CONTROL, Now(0, 0), lockstep=True, enabled=enabled)
    previews = PreviewRows(CIRCLE, TS, TS_NS, loop.preview_points, ticks)
    robot = _robot()
    run: dict = {k: [] for k in ("pose", "voltages", "currents", "messages", "X", "engagements")}
    for k in range(ticks):
        now = Now(k * TS_NS, k * TS_NS)
        if k in switches:
            loop.on_enable(switches[k], now)
        loop.on_preview(previews.at(k), now)
        pose, twist = robot.measure()
        out = loop.on_odometry(odometry_event(k * TS_NS, pose, twist), now)
        [command] = _commands(out)
        run["pose"].append(robot.plant.pose)
        run["X"].append(states_from_odometry(pose, twist))
        run["messages"].append([d.message for d in _statuses(out)])
        run["engagements"].append(int(_statuses(out)[-1].as_dict()["blend_engagements"]))
        applied, trace = robot.drive(command.values)
        run["voltages"].append(applied)
        run["currents"].append(np.abs(trace).max(axis=0))
    run = {key: np.array(value) if key != "messages" else value for key, value in run.items()}
    run["reference"] = CIRCLE.position(TS * np.arange(ticks))
    run["error"] = np.hypot(*(run["pose"][:, :2] - run["reference"][:, :2]).T)
    return run


def _enable_step(X: np.ndarray, k: int) -> np.ndarray:
    """The truth of the tick enabled at k: a reset `MotionController` on the reference plus the blend from the
    measured state (dp, dv, -a) at t_k (lockstep: the preview of the tick's own stamp, no shift).
    """
    pos, vel, acc, _ = CIRCLE.sample(k * TS + TS * np.arange(N + 1))
    blend = ReferenceBlend.engage(0.0, X[0::2] - pos[0], X[1::2] - vel[0], -acc[0], LINEAR_LIMIT_MPS2,
                                  ANGULAR_LIMIT_RADPS2, TS)
    return np.array(MotionController(ROBOT, CONTROL).step(X, pos[1:] + blend.offset(TS * np.arange(1, N + 1)),
                                                          None).voltages)


@pytest.mark.parametrize("case", ["started disabled", "disabled mid-circle"])
def test_lockstep_zero_volts_exactly_while_disabled_then_a_bumpless_start(case):
    """Started disabled (``start_enabled`` false), enabled before the preview of tick 200 (the reference 0.31 m
    along the circle); or disabled at tick 150 mid-circle and enabled again at 250. The disabled ticks, exactly
    those, are zero volts with the status ``disabled``; the enabled tick is the blend from the measured state;
    the currents after stay within the limit; the error is back at the micrometres of a run never disabled.
    """
    ticks = 1000  # 10 s: 7.5 s after the enable the error is at ~2 um
    if case == "started disabled":
        held, switches, enabled = list(range(200)), {200: True}, False
    else:
        held, switches, enabled = list(range(150, 250)), {150: False, 250: True}, True
    run = _lockstep_run(ticks, switches, enabled)
    enable = held[-1] + 1
    disabled = [k for k, messages in enumerate(run["messages"]) if "disabled" in messages]
    assert disabled == held and all(m == ["disabled"] for m in (run["messages"][k] for k in held))
    assert np.all(run["voltages"][held] == 0.0)
    if case == "started disabled":
        assert np.all(run["pose"][held] == 0.0)  # at zero volts from rest the robot never moved
        assert run["error"][enable] > 0.25  # the reference went on without it
        assert set(run["engagements"][held]) == {0} and run["engagements"][enable] == 1  # the pending start
    else:
        assert np.abs(run["voltages"][held[0] - 1]).max() > 0.5  # it was driving the circle before
        assert run["error"][enable - 1] > 0.05  # held at zero volts it fell behind (braking by back-EMF)
        assert run["engagements"][enable - 1] == 0 and run["engagements"][enable] == 1  # tick 0 started together
    np.testing.assert_allclose(run["voltages"][enable], _enable_step(run["X"][enable], enable), rtol=0, atol=1e-12)
    peak = run["currents"][enable:].max()
    tail = run["error"][-100:]
    print(f"{case}: error at the enable {run['error'][enable]:.4f} m, peak current after {peak:.4f} A, error over "
          f"the last second max {tail.max():.3g} m")
    assert peak <= 1.02 * CONTROL.current_limit_a and peak < ROBOT.nominal_current_a
    assert tail.max() < 1e-5


# realtime: faults on the odometry, a parameter change, the trajectory restarted -------------------------------
TICKS = 260
FAULTS = {120: "skip", 160: "late", 200: "duplicate"}
CHANGE_AT = 150


def _realtime_run(faults: dict[int, str] | None = None, change: dict | None = None) -> tuple[list, list]:
    """test_fault_controller's loop: the plant stepped one period under each answer, its odometry stamped on an
    ideal 10 ms grid and the paper-circle preview of the tick stamped alike, each handed in at its stamp; a late
    odometry comes 11 ms after its stamp (after the next tick's answer). `change`: control parameters set before
    tick `CHANGE_AT`. Returns the answer per tick (None: none) and every status.
    """
    settings = LoopSettings(odom_timeout_s=30.0, reference_timeout_s=30.0)
    loop = ControllerLoop(ROBOT, CONTROL, Now(T0_NS, T0_NS), settings)
    robot = _robot()
    answers, statuses, late = [], [], None
    U = (0.0, 0.0, 0.0)
    for k in range(TICKS):
        stamp = T0_NS + k * TS_NS
        now = Now(stamp, stamp)
        if change is not None and k == CHANGE_AT:
            loop.on_parameters(ROBOT, replace(CONTROL, **change), settings, True, now)
        statuses += _statuses(loop.on_preview(_preview(CIRCLE, k * TS, stamp), now))
        kind = (faults or {}).get(k)
        odom = odometry_event(stamp, *robot.measure())
        out = []
        if kind == "late":
            late = odom
        elif kind != "skip":
            out = loop.on_odometry(odom, now)
            if kind == "duplicate":
                out += loop.on_odometry(odom, Now(stamp + MS, stamp + MS))
        if late is not None and kind != "late":
            late_now = Now(late.stamp_ns + 11 * MS, late.stamp_ns + 11 * MS)
            out += loop.on_odometry(late, late_now)
            late = None
        statuses += _statuses(out)
        commands = _commands(out)
        answers.append(np.array(commands[-1].values) if commands else None)
        if commands:
            U = commands[-1].values
        robot.drive(U)
    return answers, statuses


@pytest.fixture(scope="module")
def undisturbed():
    answers, _ = _realtime_run()
    assert all(a is not None for a in answers)
    return answers


def test_realtime_skipped_late_and_duplicated_odometry_move_no_voltage_by_more_than_a_volt(undisturbed):
    answers, statuses = _realtime_run(FAULTS)
    assert [k for k, a in enumerate(answers) if a is None] == [120, 160]  # the skipped one; the late one dropped
    both = [k for k in range(TICKS) if answers[k] is not None]
    deviation = max(np.abs(answers[k] - undisturbed[k]).max() for k in both)
    peak = max(np.abs(a).max() for a in answers if a is not None)
    print(f"skip/late/duplicate: largest deviation from the undisturbed loop {deviation:.3f} V, peak {peak:.2f} V")
    assert 0.01 < deviation < 1.0 and peak < ROBOT.supply_voltage_v  # changed (the test can fail), within a volt
    assert np.array_equal(answers[119], undisturbed[119])  # until the first fault, the same loop
    last = statuses[-1].as_dict()
    assert (last["dropped_old"], last["dropped_duplicate"], last["rejected"]) == ("1", "1", "0")
    dts = {round(float(d.as_dict()["dt_s"]), 6) for d in statuses if d.message == "tracking"}
    assert dts == {0.01, 0.02}  # after the skipped and after the late tick: two periods


def test_realtime_a_stable_q_x_change_rebuilds_the_controller_without_a_voltage_step(undisturbed):
    answers, statuses = _realtime_run(change={"q_x": 2.0e6})
    window = range(CHANGE_AT - 5, CHANGE_AT + 10)
    steps = [np.abs(answers[k] - answers[k - 1]).max() for k in window]
    usual = max(np.abs(undisturbed[k] - undisturbed[k - 1]).max() for k in window)
    print(f"q_x change: largest voltage step around it {max(steps):.3f} V (undisturbed loop: {usual:.3f} V)")
    assert max(steps) < 1.0
    assert max(np.abs(answers[k] - undisturbed[k]).max() for k in range(CHANGE_AT, TICKS)) > 1e-4  # it changed
    assert {d.as_dict()["blend_engagements"] for d in statuses if d.message == "tracking"} == {"1", "2"}


def test_realtime_a_restarted_trajectory_gives_zero_then_a_bumpless_restart_that_converges():
    """The trajectory node killed after 5 s of tracking and restarted 1 s later (test_fault_controller's
    ``trajectory_node`` case): its previews stop, the watchdog answers zero (the plant then brakes at zero
    volts), and the new node's reference starts over at the circle's t = 0. The first odometry after it restarts
    the tracking with a blend; the currents of the commanded periods stay within the nominal current; 2 s after the
    blend the error is below a micrometre-scale bound. The watchdog runs every 50 ms of the clock, as its timer.
    """
    loop = ControllerLoop(ROBOT, CONTROL, Now(T0_NS, T0_NS))
    robot = _robot()
    kill, restart, end = 500, 600, 1400  # ticks: the blend after the restart lasts 5 s
    U, zero_at, rows = (0.0, 0.0, 0.0), None, []
    for k in range(end):
        stamp = T0_NS + k * TS_NS
        now = Now(stamp, stamp)
        out = []
        if k % 5 == 0:
            out += loop.on_watchdog(now)
        if not kill <= k < restart:
            started = 0 if k < kill else restart
            out += loop.on_preview(_preview(CIRCLE, (k - started) * TS, stamp), now)
        out += loop.on_odometry(odometry_event(stamp, *robot.measure()), now)
        if any(isinstance(o, Zero) for o in out):
            U = (0.0, 0.0, 0.0)
            zero_at = k if zero_at is None else zero_at
        commands = _commands(out)
        if commands:
            U = commands[-1].values
        tracking = [d.as_dict() for d in _statuses(out) if d.message == "tracking"]
        _, trace = robot.drive(U)
        rows.append((k, bool(commands), np.abs(trace).max(), tracking[-1] if tracking else None))
    assert zero_at is not None and kill < zero_at <= kill + 15  # zero within the timeout (0.1 s) and a check
    assert all(not commanded for k, commanded, _, _ in rows if zero_at <= k < restart)
    after = [(k, current, kv) for k, commanded, current, kv in rows if k >= restart and commanded]
    first = after[0][2]
    assert after[0][0] == restart and first["blend_engagements"] == "2"  # the restart at the first tick
    blend_s = float(first["blend_remaining_s"])
    error_at_restart = math.hypot(float(first["error_x_m"]), float(first["error_y_m"]))
    converged = [math.hypot(float(kv["error_x_m"]), float(kv["error_y_m"])) for k, _, kv in after
                 if (k - restart) * TS > blend_s + 2.0]
    peak = max(current for _, current, _ in after)
    print(f"trajectory restarted: zero {(zero_at - kill) * TS:.2f} s after its last preview, error at the restart "
          f"{error_at_restart * 1e3:.1f} mm, blend {blend_s:.2f} s, peak current after {peak:.3f} A, error from "
          f"T + 2 s on max {max(converged) * 1e6:.2f} um")
    assert error_at_restart > 0.01  # the new reference was far from the robot (the test can fail)
    assert peak <= 1.02 * ROBOT.nominal_current_a
    assert converged and max(converged) < 1e-5  # the micrometres of the undisturbed loop


# lockstep under use_sim_time: the watchdog's clock -----------------------------------------------------------
@pytest.mark.parametrize("sim_time", [True, False])
def test_a_slow_lockstep_loop_is_never_stale_on_the_node_clock_and_is_on_steady_time(sim_time):
    """A lockstep loop at 0.1x real time (one 10 ms tick per 100 ms of steady time), the timeouts 50 ms, the
    watchdog's timer every 25 ms of its clock: with the node clock as its clock (``use_sim_time``: the timer runs
    on /clock too) every input is at most one tick old; on steady time 100 ms, past the timeout.
    """
    timeout = 0.05
    loop = ControllerLoop(ROBOT, CONTROL, Now(0, 0), LoopSettings(odom_timeout_s=timeout,
                                                                  reference_timeout_s=timeout), lockstep=True)
    ticks = 50
    previews = PreviewRows(CIRCLE, TS, TS_NS, loop.preview_points, ticks)
    robot, states, check = _robot(), [], 0
    for k in range(ticks):
        sim = k * TS_NS
        watch = sim if sim_time else 10 * sim
        while check <= watch:  # the timer's checks due before this tick's inputs arrive
            loop.on_watchdog(Now(sim, check))
            check += 25 * MS
        loop.on_preview(previews.at(k), Now(sim, watch))
        out = loop.on_odometry(odometry_event(sim, *robot.measure()), Now(sim, watch))
        states += [d.as_dict()["watchdog"] for d in _statuses(out)]
        robot.drive(_commands(out)[0].values)
    assert len(states) == ticks
    stale = {"stale_odom", "stale_reference"} & set(states)
    assert not stale if sim_time else stale, sorted(set(states))


# through the driver chain ------------------------------------------------------------------------------------
def _chain_run(duration_s: float, previews, enable_s: float, walk=None) -> dict:
    """The chain controller (realtime, cmd_vel, started disabled) and the emulated chain, on a clock advanced 2 ms a
    step from `T0_NS`: the driver's passes polled (their odometry answered at once, the twist forwarded at that
    time), a preview every period (`previews(t_s, stamp_ns, enabled)`: the trajectory node's), the watchdog every
    50 ms, ``~/enable`` at `enable_s`. `walk` ((twist, seconds)): the robot driven first by the test's own cmd_vel
    at 30 Hz, then at rest for a second, before the controller's loop starts. Returns the twists, statuses,
    emulator and the loop's start.
    """
    chain = chain_params()
    robot = ChainRobot(ChainEmulator(RobotinoPlant(ROBOT), chain, seed=0, speed_loop_rate_hz=200.0))
    step_ns, t_ns = 2 * MS, T0_NS
    robot.poll(0.0, T0_NS)
    if walk is not None:
        twist, seconds = walk
        for j in range(round((seconds + 1.0) * 30)):
            robot.poll(j / 30, T0_NS + round(j / 30 * 1e9))
            robot.cmd_vel(twist if j < seconds * 30 else (0.0, 0.0, 0.0), j / 30)
        t_ns = T0_NS + round(round((seconds + 1.0) * 30) / 30 * 1e9)
    start_ns = t_ns
    loop = ControllerLoop(ROBOT, CONTROL, Now(start_ns, start_ns), interface="cmd_vel", chain=chain, enabled=False)
    twists, statuses, enabled, pose = [], [], False, robot.emulator.plant.pose
    while t_ns < start_ns + duration_s * 1e9:
        now, t_s = Now(t_ns, t_ns), (t_ns - start_ns) * 1e-9
        if not enabled and t_s >= enable_s:
            enabled = True
            loop.on_enable(True, now)
        if (t_ns - start_ns) % (50 * MS) == 0:
            statuses += _statuses(loop.on_watchdog(now))
        if (t_ns - start_ns) % TS_NS == 0:
            statuses += _statuses(loop.on_preview(previews(t_s, t_ns, enabled, pose), now))
        for chain_pass in robot.poll((t_ns - T0_NS) * 1e-9, t_ns):
            for m in chain_pass.odometry:
                pose = m.pose
                out = loop.on_odometry(odometry_event(m.stamp_ns, m.pose, m.twist), now)
                statuses += _statuses(out)
                for command in _commands(out):
                    twists.append((t_s, command.values))
                    robot.cmd_vel(command.values, (t_ns - T0_NS) * 1e-9)
        t_ns += step_ns
    return dict(twists=twists, statuses=statuses, emulator=robot.emulator, start_s=(start_ns - T0_NS) * 1e-9)


def test_through_the_chain_a_controller_started_disabled_sends_zero_twists_until_enabled_then_catches_up():
    """The reference runs from the start; the controller, disabled, answers every odometry with a zero twist (the
    robot never moves) until the enable 2 s later, when the reference is > 0.2 m ahead; then it catches up and
    tracks within the chain's figures (started enabled: ~1 mm), the currents within the nominal one.
    """
    hold_s, track_s = 2.0, 10.0
    run = _chain_run(hold_s + track_s, lambda t_s, stamp, enabled, pose: _preview(CIRCLE, t_s, stamp), hold_s)
    held = [t for at, t in run["twists"] if at < hold_s]
    assert len(held) > hold_s * 40 and all(t == (0.0, 0.0, 0.0) for t in held)  # every odometry (50 Hz) answered
    before = {d.message for d in run["statuses"] if d.stamp_ns < T0_NS + hold_s * 1e9}
    assert before == {"disabled"}, before
    assert any(max(map(abs, t)) > 0.05 for at, t in run["twists"] if at > hold_s)  # it drives
    trace = run["emulator"].trace
    t = np.array([r.time_s for r in trace])
    pose = np.array([r.pose for r in trace])
    assert np.abs(pose[t < hold_s]).max() == 0.0  # it never left its start
    errors = np.hypot(*(pose[:, :2] - CIRCLE.position(t)[:, :2]).T)
    moved = t[np.abs(pose).max(axis=1) > 1e-6][0]
    tail = errors[t > t[-1] - 4.0]
    peak = np.abs([r.currents for r in trace if r.time_s > hold_s]).max()
    print(f"error at the enable {errors[t <= moved].max():.3f} m, last 4 s: rms {np.sqrt(np.mean(tail**2)) * 1e3:.2f}"
          f" mm, max {tail.max() * 1e3:.2f} mm; peak current after the enable {peak:.3f} A")
    assert errors[t <= moved].max() > 0.2  # the reference had gone on without it
    assert np.sqrt(np.mean(tail**2)) < 0.005 and tail.max() < 0.01
    assert peak < ROBOT.nominal_current_a


def _moved(rows: np.ndarray, pose) -> np.ndarray:
    """(x, y, theta) rows moved rigidly onto `pose` (complex numbers: z' = z0 + e^{i theta0} z)."""
    z = (pose[0] + 1j * pose[1]) + np.exp(1j * pose[2]) * (rows[:, 0] + 1j * rows[:, 1])
    return np.column_stack((z.real, z.imag, rows[:, 2] + pose[2]))


def test_through_the_chain_the_reference_starts_at_the_enable_from_where_the_robot_stands():
    """``start_on_enable`` with ``anchor_to_robot`` (the trajectory node's, as real_robot.launch.py sets them): the
    robot driven off the origin and turned first (as identify leaves it); the reference holds at the robot (the
    node's hold previews) while the controller is disabled; at the enable paper-circle starts there, anchored. The
    robot runs the whole circle within a few mm of the circle moved onto its pose at the enable (complex numbers),
    its heading within 20 mrad, and ends where it started.
    """
    stands_s = 0.5
    state: dict = {}

    def previews(t_s: float, stamp: int, enabled: bool, pose) -> Preview:
        if not enabled:  # the hold at the newest odometry's pose
            return _hold_preview(pose, stamp)
        if "reference" not in state:  # t = 0 at the enable, anchored at the robot's pose
            state["t0"], state["pose"] = t_s, np.array(pose)
            state["reference"] = anchored(CIRCLE, pose)
        return _preview(state["reference"], t_s - state["t0"], stamp)

    run = _chain_run(stands_s + CIRCLE.duration_s + 1.0, previews, stands_s, walk=((0.15, 0.1, 0.4), 2.0))
    pose0 = state["pose"]
    assert np.hypot(*pose0[:2]) > 0.2 and abs(pose0[2]) > 0.5  # off the origin, turned
    assert all(t == (0.0, 0.0, 0.0) for at, t in run["twists"] if at < stands_s)  # zero twists while disabled
    trace = [r for r in run["emulator"].trace if r.time_s >= run["start_s"] + state["t0"]]
    t = np.array([r.time_s for r in trace]) - run["start_s"] - state["t0"]
    pose = np.array([r.pose for r in trace])
    reference = _moved(CIRCLE.position(t), pose0)
    errors = np.hypot(*(pose[:, :2] - reference[:, :2]).T)
    heading = np.abs(pose[:, 2] - reference[:, 2])
    centre = pose0[:2] + CIRCLE.radius_m * np.array([-np.sin(pose0[2]), np.cos(pose0[2])])
    radius = np.hypot(*(pose[:, :2] - centre).T)
    peak = np.abs([r.currents for r in trace]).max()
    print(f"from ({pose0[0]:.3f} m, {pose0[1]:.3f} m, {pose0[2]:.3f} rad): error max {errors.max() * 1e3:.2f} mm, "
          f"rms {np.sqrt(np.mean(errors**2)) * 1e3:.2f} mm; heading max {heading.max() * 1e3:.2f} mrad; radius "
          f"{radius.min():.4f}-{radius.max():.4f} m; end {np.hypot(*(pose[-1, :2] - pose0[:2])) * 1e3:.2f} mm from "
          f"the start; peak current {peak:.3f} A")
    assert t[-1] > CIRCLE.duration_s  # the whole circle
    assert errors.max() < 0.006 and np.sqrt(np.mean(errors**2)) < 0.003
    assert heading.max() < 0.02
    assert np.abs(radius - CIRCLE.radius_m).max() < 0.006
    assert np.hypot(*(pose[-1, :2] - pose0[:2])) < 0.003  # back where it started
    assert peak < ROBOT.nominal_current_a
