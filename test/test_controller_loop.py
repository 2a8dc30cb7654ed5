"""The controller's tick (`loop.controller_loop.ControllerLoop`) in-process, with a hand-driven clock.

Every case of the tick the controller node runs: late, stale, duplicate, reordered or lost odometry; refusals
(zero with the reason); restarts (the blend); lockstep pairing; plans and the robot's reports; the chain. Each
answer is checked against an independent truth: a `MotionController` (or `DelayCompensatingController`,
`ChainTracker`) stepped directly on the same inputs, the preview moved by its Taylor step written out here, the
blend's offset from `ReferenceBlend` at the measured state, and the counters.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from robotino_geom_mpc.control.blend import ANGULAR_LIMIT_RADPS2, LINEAR_LIMIT_MPS2, ReferenceBlend
from robotino_geom_mpc.control.chain_tracking import ChainTracker
from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController
from robotino_geom_mpc.control.motion_controller import MotionController, states_from_odometry
from robotino_geom_mpc.loop.controller_loop import ControllerLoop, LoopConfigError, LoopSettings
from robotino_geom_mpc.loop.events import (AppliedReport, Command, Diagnostic, EnabledChanged, Now, Odometry,
                                           PlanOut, Preview, Resend, Undecodable, Waiting, Zero)
from robotino_geom_mpc.model.driver_chain import chain_params
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params()
TS = CONTROL.period_s
TS_NS = round(TS * 1e9)
N = CONTROL.horizon
REF = make_reference("paper-circle")
MS = 1_000_000


def at(t_ns: int) -> Now:
    """The hand-driven clock: node clock and watchdog clock alike."""
    return Now(t_ns, t_ns)


def reference(t_s: float, points: int = N + 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference's positions, velocities, accelerations at t + j Ts, j = 0..points-1."""
    pos, vel, acc, _ = REF.sample(t_s + TS * np.arange(points))
    return pos, vel, acc


def preview(stamp_ns: int, points: int = N + 1, frame: str = "odom", poison: float | None = None) -> Preview:
    """The preview message's values at its stamp (the trajectory node's: pose, yaw quaternion, vel, acc)."""
    pos, vel, acc = reference(stamp_ns * 1e-9, points)
    values: list[float] = []
    for p, v, a in zip(pos.tolist(), vel.tolist(), acc.tolist()):
        values += (p[0], p[1], 0.0, 0.0, math.sin(p[2] / 2), math.cos(p[2] / 2), *v, *a)
    if poison is not None:
        values[0] = poison
    return Preview(stamp_ns, frame, tuple(values))


def odometry(stamp_ns: int, pose=(0.01, -0.02, 0.03), twist=(0.05, 0.0, 0.1)) -> Odometry:
    x, y, th = pose
    return Odometry(stamp_ns, (x, y, 0.0, 0.0, math.sin(th / 2), math.cos(th / 2), *twist))


def state(odom: Odometry) -> np.ndarray:
    x, y, _, _, qz, qw, vx, vy, w = odom.values
    return states_from_odometry((x, y, 2 * math.atan2(qz, qw)), (vx, vy, w))


def same(command: Command, stamp_ns: int, values) -> None:
    """`command` answers `stamp_ns` with `values` (1e-12: the truth's heading is the reference's, the loop's the one
    decoded from the preview's quaternion).
    """
    assert command.stamp_ns == stamp_ns
    np.testing.assert_allclose(command.values, values, rtol=0, atol=1e-12)


def commands(outputs) -> list[Command]:
    return [o for o in outputs if isinstance(o, Command)]


def zeros(outputs) -> list[str]:
    return [o.reason for o in outputs if isinstance(o, Zero)]


def status(outputs) -> dict[str, str]:
    """The key/values of the last status among `outputs`."""
    return [o for o in outputs if isinstance(o, Diagnostic)][-1].as_dict()


def loop(lockstep: bool = False, **options) -> ControllerLoop:
    return ControllerLoop(ROBOT, CONTROL, at(0), lockstep=lockstep, **options)


def blended_step(controller: MotionController, odom: Odometry, stamp_ns: int, preview_ns: int,
                 limits=(LINEAR_LIMIT_MPS2, ANGULAR_LIMIT_RADPS2)) -> np.ndarray:
    """Truth of a (re)start tick: reset, the blend from the measured state (dp, dv, -a), the preview moved."""
    pos, vel, acc = reference(preview_ns * 1e-9)
    dt = (stamp_ns - preview_ns) * 1e-9
    pos = pos + dt * vel + 0.5 * dt * dt * acc  # the Taylor step, written out
    vel = vel + dt * acc
    X = state(odom)
    blend = ReferenceBlend.engage(0.0, X[0::2] - pos[0], X[1::2] - vel[0], -acc[0], *limits, TS)
    controller.reset()
    return np.array(controller.step(X, pos[1:] + blend.offset(TS * np.arange(1, N + 1)), None).voltages)


# lockstep ------------------------------------------------------------------------------------------------------
def test_lockstep_tick_zero_starts_together_and_equals_a_direct_step():
    lp = loop(lockstep=True)
    odom = odometry(0, pose=tuple(reference(0.0)[0][0]), twist=(0.0, 0.0, 0.0))
    assert commands(lp.on_odometry(odom, at(0))) == []  # waits for the preview of its stamp
    out = lp.on_preview(preview(0), at(1 * MS))
    truth = MotionController(ROBOT, CONTROL)
    pos = reference(0.0)[0]
    truth.start_at(*pos[0])
    expected = truth.step(state(odom), pos[1:], None).voltages
    assert commands(out) == [Command(0, tuple(expected))]
    assert status(out)["blend_engagements"] == "0" and status(out)["preview_stamp_ns"] == "0"
    # the next tick, preview first: one period on (dt None), no blend
    lp.on_preview(preview(TS_NS), at(2 * MS))
    odom1 = odometry(TS_NS)
    out = lp.on_odometry(odom1, at(3 * MS))
    pos = reference(TS)[0]
    assert commands(out) == [Command(TS_NS, tuple(truth.step(state(odom1), pos[1:], None).voltages))]


def test_lockstep_duplicate_reordered_and_lost():
    lp = loop(lockstep=True)
    truth = MotionController(ROBOT, CONTROL)
    truth.start_at(*reference(0.0)[0][0])
    o0, o1, o2 = (odometry(k * TS_NS) for k in range(3))
    lp.on_preview(preview(0), at(0))
    lp.on_odometry(o0, at(0))
    truth.step(state(o0), reference(0.0)[0][1:], None)
    # duplicate (the plant resent the tick): a resend request, dropped, counted
    out = lp.on_odometry(o0, at(1))
    assert [o for o in out if isinstance(o, Resend)] == [Resend(0)] and commands(out) == []
    assert status(out)["dropped_duplicate"] == "1"
    # two odometries wait; their previews come in reverse order: answered in arrival order
    assert commands(lp.on_odometry(o1, at(2)) + lp.on_odometry(o2, at(3))) == []
    assert commands(lp.on_preview(preview(2 * TS_NS), at(4))) == []
    out = lp.on_preview(preview(TS_NS), at(5))
    e1 = truth.step(state(o1), reference(TS)[0][1:], None).voltages
    e2 = truth.step(state(o2), reference(2 * TS)[0][1:], None).voltages
    assert commands(out) == [Command(TS_NS, tuple(e1)), Command(2 * TS_NS, tuple(e2))]
    # tick 3 lost: tick 4 steps with dt = 2 Ts
    o4 = odometry(4 * TS_NS)
    lp.on_preview(preview(4 * TS_NS), at(6))
    out = lp.on_odometry(o4, at(7))
    e4 = truth.step(state(o4), reference(4 * TS)[0][1:], 2 * TS_NS * 1e-9).voltages
    assert commands(out) == [Command(4 * TS_NS, tuple(e4))]
    assert float(status(out)["dt_s"]) == pytest.approx(2 * TS)
    # an odometry older than the last used: dropped
    out = lp.on_odometry(odometry(3 * TS_NS), at(8))
    assert commands(out) == [] and status(out)["dropped_old"] == "1"


def test_lockstep_refused_preview_zeroes_its_tick():
    lp = loop(lockstep=True)
    lp.on_odometry(odometry(0), at(0))
    out = lp.on_preview(preview(0, poison=math.nan), at(1))
    assert zeros(out) == ["preview_non_finite"] and commands(out) == []
    assert status(out)["last_refusal"] == "preview_non_finite" and status(out)["rejected"] == "2"
    # a wrongly sized preview of the next tick, the odometry after it
    lp.on_preview(preview(TS_NS, points=N), at(2))
    out = lp.on_odometry(odometry(TS_NS), at(3))
    assert zeros(out) == ["preview_size"]


def test_lockstep_start_disabled_keeps_the_start_and_waits_log():
    lp = loop(lockstep=True, enabled=False)
    odom = odometry(0)
    lp.on_preview(preview(0), at(0))
    out = lp.on_odometry(odom, at(0))
    assert commands(out) == [Command(0, (0.0, 0.0, 0.0))] and status(out) == {**status(out)}
    assert [o.message for o in out if isinstance(o, Diagnostic)] == ["disabled"]
    assert lp.on_enable(True, at(1)) [0] == EnabledChanged(True)
    lp.on_preview(preview(TS_NS), at(2))
    o1 = odometry(TS_NS)
    out = lp.on_odometry(o1, at(3))
    # the pending start engages at the first tick enabled (not t = 0): the blend from the measured state
    assert commands(out) == [Command(TS_NS, tuple(blended_step(MotionController(ROBOT, CONTROL), o1, TS_NS, TS_NS)))]
    # the watchdog only says what is missing in lockstep: an odometry waiting for its preview
    lp.on_odometry(odometry(2 * TS_NS), at(4))
    out = lp.on_watchdog(at(4 + 200 * MS))
    assert zeros(out) == [] and out == [Waiting("preview_of_stamp", 0.2, 2 * TS_NS)]


# realtime ------------------------------------------------------------------------------------------------------
def test_realtime_start_blend_shift_and_stamp_checks():
    lp = loop()
    clock = 1_000 * MS
    lp.on_preview(preview(clock), at(clock))
    odom = odometry(clock + 3 * MS)
    out = lp.on_odometry(odom, at(clock + 4 * MS))
    truth = MotionController(ROBOT, CONTROL)
    [command] = commands(out)
    same(command, clock + 3 * MS, blended_step(truth, odom, clock + 3 * MS, clock))
    assert status(out)["blend_engagements"] == "1" and status(out)["preview_stamp_ns"] == str(clock)
    # the next, 8 ms later: dt = 8 ms, the same preview moved further
    odom2 = odometry(clock + 11 * MS, pose=(0.012, -0.02, 0.031))
    out = lp.on_odometry(odom2, at(clock + 12 * MS))
    pos, vel, acc = reference(clock * 1e-9)
    dt = 11e-3
    moved = pos + dt * vel + 0.5 * dt * dt * acc
    blend = ReferenceBlend.engage(0.0, state(odom).take([0, 2, 4]) - (pos + 3e-3 * vel + 4.5e-6 * acc)[0],
                                  state(odom).take([1, 3, 5]) - (vel + 3e-3 * acc)[0], -acc[0],
                                  LINEAR_LIMIT_MPS2, ANGULAR_LIMIT_RADPS2, TS)
    offsets = blend.offset(8e-3 + TS * np.arange(1, N + 1))
    expected = truth.step(state(odom2), moved[1:] + offsets, 8e-3).voltages
    np.testing.assert_allclose(commands(out)[0].values, expected, rtol=0, atol=1e-12)
    kv = status(out)  # the error against the reference at the odometry's stamp (without the blend), the interval
    error = state(odom2)[0::2] - moved[0]
    assert [float(kv[k]) for k in ("error_x_m", "error_y_m")] == pytest.approx(error[:2].tolist(), abs=1e-9)
    assert float(kv["dt_s"]) == pytest.approx(8e-3, abs=1e-12) and kv["preview_stamp_ns"] == str(clock)
    assert kv["clock_ns"] == str(clock + 12 * MS)  # the clock it was handed: what a replay takes it at
    # late (older), duplicate, stale and future stamps
    out = lp.on_odometry(odometry(clock + 5 * MS), at(clock + 13 * MS))
    assert commands(out) == [] and zeros(out) == [] and status(out)["dropped_old"] == "1"
    out = lp.on_odometry(odometry(clock + 11 * MS), at(clock + 13 * MS))
    assert commands(out) == [] and status(out)["dropped_duplicate"] == "1"
    out = lp.on_odometry(odometry(clock + 12 * MS), at(clock + 500 * MS))
    assert zeros(out) == ["stale"] and status(out)["clock_ns"] == str(clock + 500 * MS)
    out = lp.on_odometry(odometry(clock + 900 * MS), at(clock + 13 * MS))
    assert zeros(out) == ["future"]
    assert status(out)["rejected"] == "2" and status(out)["last_refusal"] == "future"


@pytest.mark.parametrize("case,reason", [
    ("nan_odom", "non_finite"), ("quaternion", "quaternion_norm"), ("implausible", "implausible"),
    ("frame", "frame"), ("size", "size"), ("nan_preview", "non_finite"), ("malformed", "malformed"),
])
def test_realtime_refusals_answer_zero_with_the_reason(case, reason):
    lp = loop()
    clock = 1_000 * MS
    lp.on_preview(preview(clock), at(clock))
    odom = odometry(clock + MS)
    inputs = {
        "nan_odom": lambda: lp.on_odometry(odometry(clock + MS, pose=(math.nan, 0.0, 0.0)), at(clock + MS)),
        "quaternion": lambda: lp.on_odometry(Odometry(clock + MS, (0.0,) * 9), at(clock + MS)),
        "implausible": lambda: lp.on_odometry(odometry(clock + MS, twist=(1e3, 0.0, 0.0)), at(clock + MS)),
        "frame": lambda: lp.on_preview(preview(clock + MS, frame="robot2/odom"), at(clock + MS)),
        "size": lambda: lp.on_preview(preview(clock + MS, points=3), at(clock + MS)),
        "nan_preview": lambda: lp.on_preview(preview(clock + MS, poison=math.inf), at(clock + MS)),
        "malformed": lambda: lp.on_undecodable(Undecodable("odom", None, "malformed", "bad bytes"), at(clock + MS)),
    }
    out = inputs[case]()
    assert zeros(out) == [reason] and commands(out) == []
    diag = [o for o in out if isinstance(o, Diagnostic)][-1]
    assert diag.level == 2 and f"({reason})" in diag.message and diag.as_dict()["last_refusal"] == reason
    # the loop goes on: the next odometry is answered (the start blend)
    assert len(commands(lp.on_odometry(odometry(clock + 2 * MS), at(clock + 2 * MS)))) == 1
    del odom


def test_realtime_disabled_enable_watchdog_and_parameters_restart_bumplessly():
    lp = loop(enabled=False)
    clock = 1_000 * MS
    lp.on_preview(preview(clock), at(clock))
    out = lp.on_odometry(odometry(clock + MS), at(clock + MS))
    assert commands(out) == [Command(clock + MS, (0.0, 0.0, 0.0))] and status(out)["blend_engagements"] == "0"
    lp.on_enable(True, at(clock + 2 * MS))
    out = lp.on_odometry(odometry(clock + 9 * MS), at(clock + 9 * MS))
    assert status(out)["blend_engagements"] == "1"  # the start
    # disabled and enabled again: a restart ("enable")
    lp.on_enable(False, at(clock + 10 * MS))
    lp.on_odometry(odometry(clock + 17 * MS), at(clock + 17 * MS))
    assert [o for o in lp.on_enable(True, at(clock + 18 * MS)) if isinstance(o, EnabledChanged)] == [
        EnabledChanged(True)]
    odom = odometry(clock + 25 * MS)
    out = lp.on_odometry(odom, at(clock + 25 * MS))
    truth = MotionController(ROBOT, CONTROL)
    same(commands(out)[0], clock + 25 * MS, blended_step(truth, odom, clock + 25 * MS, clock))
    # the watchdog: stale odometry -> zero, the stamps forgotten, a restart at the data's return
    assert zeros(lp.on_watchdog(at(clock + 60 * MS))) == []
    out = lp.on_watchdog(at(clock + 200 * MS))
    assert zeros(out) == ["watchdog"] and status(out)["watchdog"] == "stale_odom"
    lp.on_preview(preview(clock + 190 * MS), at(clock + 201 * MS))
    odom = odometry(clock + 195 * MS)
    out = lp.on_odometry(odom, at(clock + 202 * MS))
    same(commands(out)[0], clock + 195 * MS, blended_step(truth, odom, clock + 195 * MS, clock + 190 * MS))
    assert status(out)["blend_engagements"] == "3"
    # new parameters: a rebuilt controller, a restart with the new blend limits
    settings = LoopSettings(blend_acceleration_mps2=0.1)
    control = replace(CONTROL, horizon=N)
    lp.on_parameters(ROBOT, control, settings, True, at(clock + 203 * MS))
    odom = odometry(clock + 203 * MS)
    out = lp.on_odometry(odom, at(clock + 203 * MS))
    expected = blended_step(MotionController(ROBOT, CONTROL), odom, clock + 203 * MS, clock + 190 * MS,
                            (0.1, ANGULAR_LIMIT_RADPS2))
    same(commands(out)[0], clock + 203 * MS, expected)
    assert lp.on_stop(at(clock + 204 * MS)) == [Zero("stop")]


def test_reference_jump_restarts():
    lp = loop()
    clock = 1_000 * MS
    lp.on_preview(preview(clock), at(clock))
    lp.on_odometry(odometry(clock + MS), at(clock + MS))
    jumped = preview(clock + TS_NS)
    jumped = Preview(jumped.stamp_ns, "odom", (jumped.values[0] + 0.1, *jumped.values[1:]))
    lp.on_preview(jumped, at(clock + TS_NS))
    out = lp.on_odometry(odometry(clock + TS_NS + MS), at(clock + TS_NS + MS))
    assert status(out)["blend_engagements"] == "2"


# plans ---------------------------------------------------------------------------------------------------------
def test_plans_reports_held_loss_duplicates_and_window():
    lp = loop(lockstep=True, plans=True)
    points = lp.preview_points + 1
    truth = DelayCompensatingController(ROBOT, CONTROL)
    pos0 = reference(0.0, points)[0]
    truth.start_at(*pos0[0])
    o0 = odometry(0)
    lp.on_preview(preview(0, points), at(0))
    out = lp.on_odometry(o0, at(0))
    plan0 = truth.plan(0.0, state(o0), pos0[1:])
    assert [o.plan for o in out if isinstance(o, PlanOut)] == [plan0]
    assert commands(out) == [Command(0, tuple(plan0.entries[0]))]
    # tick 1 lost on the up-link; tick 2's odometry waits; a report that came meanwhile is held for it
    o2 = odometry(2 * TS_NS)
    lp.on_odometry(o2, at(1))
    receipt = AppliedReport(0.015, 0.0, -1, None, True)
    assert lp.on_report(receipt, at(2)) == [] and lp.reports_received == 0
    out = lp.on_preview(preview(2 * TS_NS, points), at(3))
    plan2 = truth.plan(2 * TS_NS * 1e-9, state(o2), reference(2 * TS, points)[0][1:])
    truth.report_receipt(0.0, 0.015, True)
    assert commands(out) == [Command(2 * TS_NS, tuple(plan2.entries[0]))]
    assert lp.reports_received == 1 and status(out)["odometry_missing"] == "1"
    # a report far off the newest odometry: refused, counted
    lp.on_report(AppliedReport(100.0, 0.0, 0, (1.0, 1.0, 1.0)), at(4))
    assert (lp.refused_reports, lp.reports_received) == (1, 2)
    # an applied period without a plan (exhaustion) reaches the controller
    lp.on_report(AppliedReport(2 * TS, None, -1, (0.0, 0.0, 0.0)), at(5))
    truth.report_applied(2 * TS, None, 0)
    o3 = odometry(3 * TS_NS)
    lp.on_preview(preview(3 * TS_NS, points), at(6))
    out = lp.on_odometry(o3, at(7))
    plan3 = truth.plan(3 * TS_NS * 1e-9, state(o3), reference(3 * TS, points)[0][1:])
    [made] = [o.plan for o in out if isinstance(o, PlanOut)]
    assert (made.basis_s, made.times_s) == (plan3.basis_s, plan3.times_s)
    np.testing.assert_allclose(made.entries, plan3.entries, rtol=0, atol=1e-12)
    assert status(out)["exhausted_periods"] == str(truth.statistics().exhausted_periods)
    # a duplicate odometry over the link: dropped
    assert commands(lp.on_odometry(o3, at(8))) == []


def _is_stop(plan, basis_s: float) -> None:
    """`plan` is zeros from basis + lead_min Ts to basis + (lead_max + plan length) Ts (the end of the latest plan
    of an odometry up to the basis), a period each.
    """
    periods = np.arange(CONTROL.lead_min_periods, CONTROL.lead_max_periods + CONTROL.plan_length)
    assert plan.basis_s == basis_s and plan.period_s == TS and plan.problem() is None
    np.testing.assert_allclose(plan.times_s, basis_s + TS * periods, rtol=0, atol=1e-9)
    assert plan.entries == ((0.0, 0.0, 0.0),) * len(periods)


def test_plans_disabled_sends_a_plan_of_zeros_that_outlasts_every_plan_sent():
    """Disabled with plans: each odometry gets a plan of zeros (newer than every plan sent and ending after the
    latest a plan can reach, it replaces those the robot holds, so the robot stops instead of playing them out),
    and the plain zero; no plan of the MPC.
    """
    lp = loop(plans=True)
    points = lp.preview_points + 1
    lp.on_preview(preview(0, points), at(0))
    [sent] = [o.plan for o in lp.on_odometry(odometry(0), at(0)) if isinstance(o, PlanOut)]  # enabled: the MPC's
    lp.on_enable(False, at(1))
    stamp = TS_NS
    lp.on_preview(preview(stamp, points), at(stamp))
    out = lp.on_odometry(odometry(stamp), at(stamp + MS))
    [plan] = [o.plan for o in out if isinstance(o, PlanOut)]
    _is_stop(plan, stamp * 1e-9)
    assert plan.end_s >= sent.end_s
    assert commands(out) == [Command(stamp, (0.0, 0.0, 0.0))]
    assert [o.message for o in out if isinstance(o, Diagnostic)] == ["disabled"]


def test_plans_a_zero_comes_with_a_plan_of_zeros_once_per_odometry_planned_from():
    """Realtime with plans: the watchdog's zero (and a refused input's) also sends a plan of zeros just after the
    newest odometry planned from (10 us: a basis of its own), once until a newer plan; the plans held would run on.
    """
    lp = loop(plans=True)
    points = lp.preview_points + 1
    lp.on_preview(preview(0, points), at(0))
    lp.on_odometry(odometry(0), at(0))
    late = 10 * round(CONTROL.period_s * 1e9) + round(LoopSettings().odom_timeout_s * 1e9)
    out = lp.on_watchdog(at(late))
    assert zeros(out) == ["watchdog"]
    [plan] = [o.plan for o in out if isinstance(o, PlanOut)]
    _is_stop(plan, 1e-5)
    assert not [o for o in lp.on_watchdog(at(late + TS_NS)) if isinstance(o, PlanOut)]  # once


# the chain -----------------------------------------------------------------------------------------------------
def test_chain_two_samples_a_stamp_and_noted_zeros():
    chain = chain_params()
    with pytest.raises(LoopConfigError):
        loop(lockstep=True, interface="cmd_vel", chain=chain)
    lp = loop(interface="cmd_vel", chain=chain, enabled=False)
    truth = ChainTracker(chain, TS)
    clock = 1_000 * MS
    lp.on_preview(preview(clock), at(clock))
    held = (clock, *reference(clock * 1e-9))
    # disabled: a zero answer, noted in the command model at the clock handed in
    out = lp.on_odometry(odometry(clock + 5 * MS), at(clock + 6 * MS))
    assert commands(out) == [Command(clock + 5 * MS, (0.0, 0.0, 0.0))]
    lp.on_enable(True, at(clock + 7 * MS))
    answers = []
    for stamp, now in ((clock + 25 * MS, clock + 26 * MS), (clock + 25 * MS, clock + 27 * MS),
                       (clock + 45 * MS, clock + 46 * MS)):  # two samples of one stamp, both used
        odom = odometry(stamp)
        out = lp.on_odometry(odom, at(now))
        assert status(out)["preview_stamp_ns"] == str(clock) and status(out)["clock_ns"] == str(now)
        answers += commands(out)
    # the truth: the tracker stepped directly, the disabled zero noted (its epoch starts at the first step)
    expected = []
    for stamp, now in ((clock + 25 * MS, clock + 26 * MS), (clock + 25 * MS, clock + 27 * MS),
                       (clock + 45 * MS, clock + 46 * MS)):
        expected.append(Command(stamp, tuple(truth.step(stamp, now, state(odometry(stamp)), held))))
    assert answers == expected
    # a refusal's zero is noted too: the next twist equals the tracker's after note_zero at that clock
    lp.on_odometry(odometry(clock + 50 * MS, pose=(math.nan, 0, 0)), at(clock + 51 * MS))
    truth.note_zero(clock + 51 * MS)
    out = lp.on_odometry(odometry(clock + 65 * MS), at(clock + 66 * MS))
    assert commands(out) == [Command(clock + 65 * MS, tuple(truth.step(clock + 65 * MS, clock + 66 * MS,
                                                                       state(odometry(clock + 65 * MS)), held)))]


# refusals moved here from the DDS tests (test_controller_node, test_controller_hardening) --------------------
def _speed_bound_mps() -> float:
    """The forward body speed at which the fastest motor turns at twice its no-load speed U_supply / Km.

    From the geometry alone: the wheels sit at phi_i = 0, 2 pi / 3, 4 pi / 3 and roll along (sin(phi_i),
    cos(phi_i)) in base_link, so a forward speed v turns motor i at gear / r |sin(phi_i)| v.
    """
    phi = np.array([0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0])
    fastest_per_mps = ROBOT.gear_ratio / ROBOT.r * np.abs(np.sin(phi)).max()
    return 2.0 * ROBOT.supply_voltage_v / ROBOT.torque_constant_n_m_per_a / fastest_per_mps


def _with_quaternion(values: tuple[float, ...], offset: int, q) -> tuple[float, ...]:
    out = list(values)
    out[offset:offset + 4] = q
    return tuple(out)


@pytest.mark.parametrize("what, q, reason", [
    ("odom", (0.0, 0.0, 0.0, 0.0), "quaternion_norm"),  # was read as yaw 0
    ("odom", (0.0, 0.0, 0.5, 0.5), "quaternion_norm"),  # was read as pi/2 (atan2 of an unnormalised quaternion)
    ("odom", (0.1, 0.0, 0.0, math.sqrt(1 - 0.01)), "quaternion_tilt"),  # 0.2 rad of roll
    ("reference_preview", (0.0, 0.0, 0.0, 0.0), "preview_quaternion_norm"),
    ("reference_preview", (0.0, 0.06, 0.0, math.sqrt(1 - 0.0036)), "preview_quaternion_tilt"),
])
def test_lockstep_a_quaternion_that_is_no_yaw_is_refused_with_zero(what, q, reason):
    lp = loop(lockstep=True)
    stamp = 700 * TS_NS
    p, o = preview(stamp), odometry(stamp)
    if what == "odom":
        o = Odometry(stamp, _with_quaternion(o.values, 2, q))
    else:  # point 2's rotation
        p = Preview(stamp, "odom", _with_quaternion(p.values, 2 * 12 + 2, q))
    out = lp.on_preview(p, at(0)) + lp.on_odometry(o, at(1))
    assert zeros(out) == [reason] and commands(out) == []
    diag = [d for d in out if isinstance(d, Diagnostic)][-1]
    assert diag.level == 2 and reason in diag.message and diag.as_dict()["last_refusal"] == reason


@pytest.mark.parametrize("case, reason", [
    ("twist above the bound", "implausible"), ("position 1000 km out", "implausible"),
    ("preview 1000 km out", "preview_implausible"), ("twist below the bound", None),
])
def test_lockstep_an_input_that_is_no_measurement_is_refused(case, reason):
    lp = loop(lockstep=True)
    stamp = 300 * TS_NS
    p, o = preview(stamp), odometry(stamp, twist=(0.0, 0.0, 0.0))
    if case == "twist above the bound":
        o = odometry(stamp, twist=(1.05 * _speed_bound_mps(), 0.0, 0.0))
    elif case == "twist below the bound":
        o = odometry(stamp, twist=(0.95 * _speed_bound_mps(), 0.0, 0.0))
    elif case == "position 1000 km out":
        o = odometry(stamp, pose=(1.5e6, 0.0, 0.0))
    else:
        p = Preview(stamp, "odom", (*p.values[:3 * 12 + 1], -1.5e6, *p.values[3 * 12 + 2:]))  # point 3's y
    out = lp.on_preview(p, at(0)) + lp.on_odometry(o, at(1))
    if reason is None:  # tracked
        assert len(commands(out)) == 1 and zeros(out) == [] and status(out)["rejected"] == "0"
    else:
        assert zeros(out) == [reason] and commands(out) == [] and status(out)["last_refusal"] == reason


@pytest.mark.parametrize("frame", ["hard/odom", "map", ""])
def test_lockstep_a_preview_in_another_frame_is_refused_naming_both_frames(frame):
    lp = loop(lockstep=True)
    stamp = 500 * TS_NS
    out = lp.on_preview(preview(stamp, frame=frame), at(0)) + lp.on_odometry(odometry(stamp), at(1))
    diag = [d for d in out if isinstance(d, Diagnostic)][-1]
    assert zeros(out) == ["preview_frame"] and diag.as_dict()["last_refusal"] == "preview_frame"
    assert f"'{frame}'" in diag.message and "'odom'" in diag.message
    out = lp.on_preview(preview(stamp + TS_NS), at(2)) + lp.on_odometry(odometry(stamp + TS_NS), at(3))
    assert len(commands(out)) == 1 and status(out)["blend_engagements"] == "1"  # the same in 'odom': tracked


# more of the tick ----------------------------------------------------------------------------------------------
def test_lockstep_previews_resent_answer_each_tick_once():
    """The trajectory resends previews on purpose (keyed by stamp): no drop, no refusal, one answer a tick."""
    lp = loop(lockstep=True)
    truth = MotionController(ROBOT, CONTROL)
    truth.start_at(*reference(0.0)[0][0])
    out, expected = [], []
    for k in range(3):
        p, o = preview(k * TS_NS), odometry(k * TS_NS)
        out += lp.on_preview(p, at(4 * k)) + lp.on_preview(p, at(4 * k + 1))  # sent twice before its odometry
        out += lp.on_odometry(o, at(4 * k + 2)) + lp.on_preview(p, at(4 * k + 3))  # and once after
        expected.append(truth.step(state(o), reference(k * TS)[0][1:], None).voltages)
    assert [c.stamp_ns for c in commands(out)] == [0, TS_NS, 2 * TS_NS] and zeros(out) == []
    for command, values in zip(commands(out), expected):
        same(command, command.stamp_ns, values)
    kv = status(out)
    assert (kv["rejected"], kv["dropped_duplicate"], kv["dropped_old"]) == ("0", "0", "0")


def test_lockstep_plans_reordered_odometry_is_dropped_and_its_held_reports_taken():
    lp = loop(lockstep=True, plans=True)
    points = lp.preview_points + 1
    for k in range(3):
        lp.on_preview(preview(k * TS_NS, points), at(k))
    lp.on_odometry(odometry(0), at(3))
    # tick 2 overtakes tick 1 on the up-link: tick 2 is planned, tick 1 dropped as old
    out = lp.on_odometry(odometry(2 * TS_NS), at(4))
    assert [c.stamp_ns for c in commands(out)] == [2 * TS_NS]
    out = lp.on_odometry(odometry(TS_NS), at(5))
    assert commands(out) == [] and status(out)["dropped_old"] == "1"
    # an odometry waiting for its preview holds the reports that come meanwhile; planned, it hands them on
    lp.on_odometry(odometry(3 * TS_NS), at(6))
    lp.on_report(AppliedReport(0.02, 0.0, 0, (0.1, 0.2, 0.3)), at(7))
    lp.on_report(Undecodable("command_applied", None, "length", "a report has one point"), at(8))
    assert (lp.reports_received, lp.refused_reports) == (0, 0)
    out = lp.on_preview(preview(3 * TS_NS, points), at(9))
    assert [c.stamp_ns for c in commands(out)] == [3 * TS_NS] and (lp.reports_received, lp.refused_reports) == (2, 1)


def test_realtime_watchdog_stale_reference_and_a_clock_that_went_back():
    lp = loop()
    t = 1_000 * MS
    lp.on_preview(preview(t), at(t))
    lp.on_odometry(odometry(t + MS), at(t + MS))
    for k in range(2, 20):  # odometry keeps coming, the reference stops
        out = lp.on_odometry(odometry(t + k * 10 * MS), at(t + k * 10 * MS))
    assert commands(out) == []  # a reference older than its timeout is not used
    out = lp.on_watchdog(at(t + 191 * MS))
    assert zeros(out) == ["watchdog"] and status(out)["watchdog"] == "stale_reference"
    # the node clock went back (a simulator reset) while the watchdog's steady clock went on: the stamps used so
    # far are forgotten, an input stamped before them is taken, with a bumpless restart
    back = Now(t - 500 * MS, t + 300 * MS)
    lp.on_preview(preview(t - 500 * MS), back)
    out = lp.on_odometry(odometry(t - 499 * MS), Now(t - 499 * MS, t + 301 * MS))
    assert [c.stamp_ns for c in commands(out)] == [t - 499 * MS] and status(out)["blend_engagements"] == "2"
    assert status(out)["watchdog"] == "stale_reference"  # until the next check
    assert lp.on_watchdog(Now(t - 498 * MS, t + 302 * MS)) == [] and lp.watchdog_state == "ok"


def test_chain_drops_an_older_stamp_and_refuses_an_implausible_pose():
    lp = loop(interface="cmd_vel", chain=chain_params())
    t = 1_000 * MS
    lp.on_preview(preview(t), at(t))
    assert len(commands(lp.on_odometry(odometry(t + 20 * MS), at(t + 21 * MS)))) == 1
    out = lp.on_odometry(odometry(t + 10 * MS), at(t + 22 * MS))
    assert commands(out) == [] and zeros(out) == [] and status(out)["dropped_old"] == "1"
    out = lp.on_odometry(odometry(t + 20 * MS, pose=(1e9, 0.0, 0.0)), at(t + 23 * MS))
    assert zeros(out) == ["implausible"]


def test_realtime_a_longer_preview_covers_the_periods_until_the_next():
    """A preview of N + 10 points (``preview_every`` 10) stamped t_p answers odometries 0..9 periods after it as
    the exact N + 1 preview of the reference sampled at t_p + m Ts would, moved by the remaining dt (the Taylor
    step written out); a new preview of the same reference 10 periods on is no jump; the longest one is taken.
    """
    every, clock = 10, 1_000 * MS
    lp, truth_loop = loop(settings=replace(LoopSettings(), reference_timeout_s=0.3)), loop()
    assert zeros(lp.on_preview(preview(clock, N + every), at(clock))) == []
    for m in (0, 3, 9):
        stamp = clock + m * TS_NS + 4 * MS
        odom = odometry(stamp, pose=(0.01 + 0.001 * m, -0.02, 0.03))
        out = lp.on_odometry(odom, at(stamp + MS))
        truth_loop.on_preview(preview(clock + m * TS_NS), at(stamp))  # the exact preview of t_p + m Ts
        expected = commands(truth_loop.on_odometry(odom, at(stamp + MS)))
        np.testing.assert_allclose(commands(out)[0].values, expected[0].values, rtol=0, atol=1e-9)
        assert status(out)["preview_stamp_ns"] == str(clock)
    out = lp.on_preview(preview(clock + every * TS_NS, N + every), at(clock + every * TS_NS))
    stamp = clock + every * TS_NS + 4 * MS
    out = lp.on_odometry(odometry(stamp, pose=(0.02, -0.02, 0.03)), at(stamp + MS))
    assert status(out)["blend_engagements"] == "1" and status(out)["preview_stamp_ns"] == str(clock + every * TS_NS)
    # past the preview's rows (a next preview lost): its last rows, carried to second order from there
    late = clock + every * TS_NS + 14 * TS_NS + 2 * MS
    out = lp.on_odometry(odometry(late, pose=(0.03, -0.02, 0.03)), at(late))
    pos, vel, acc = reference((clock + every * TS_NS) * 1e-9, N + every)
    dt = (late - clock - every * TS_NS - (every - 1) * TS_NS) * 1e-9
    moved = pos[every - 1:] + dt * vel[every - 1:] + 0.5 * dt * dt * acc[every - 1:]
    error = state(odometry(late, pose=(0.03, -0.02, 0.03)))[0::2] - moved[0]
    kv = status(out)
    assert [float(kv[k]) for k in ("error_x_m", "error_y_m")] == pytest.approx(error[:2].tolist(), abs=1e-9)
