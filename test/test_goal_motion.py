"""Goal motions (reference.goal_motion) and the goals reference (reference.goals) against independent truths.

Truths: the septic smoothstep of reference.time_law (a rest-to-rest goal motion is exactly it), finite differences
of the sampled positions (the analytic derivatives), a dense resampling with `model.dynamics.wheel_rim_speeds`
per sample (the limits), and the goal itself (the end).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from robotino_geom_mpc.reference.goal_motion import BrakingMotion, GoalError, MotionLimits, PolynomialMotion, \
    nominal_rim_speed
from robotino_geom_mpc.reference.goals import SHIFT_SHARE, GoalReference
from robotino_geom_mpc.model.dynamics import wheel_rim_speeds
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.reference.time_law import septic
from robotino_geom_mpc.reference.trajectories import preview

pytestmark = pytest.mark.unit

ROBOT, _ = load_params(default_params_file())


def limits(**change: float) -> MotionLimits:
    values = dict(velocity_mps=0.4, acceleration_mps2=0.4, jerk_mps3=2.0, angular_velocity_radps=1.5,
                  angular_acceleration_radps2=1.5, angular_jerk_radps3=8.0, rim_speed_mps=nominal_rim_speed(ROBOT))
    values.update(change)
    return MotionLimits(robot=ROBOT, **values)


def usage(theta: np.ndarray, vel: np.ndarray, acc: np.ndarray, jerk: np.ndarray, lim: MotionLimits) -> float:
    """Independent check: per sample and axis |value| / limit, and every wheel's rim speed."""
    bounds = np.array([[lim.velocity_mps] * 2 + [lim.angular_velocity_radps],
                       [lim.acceleration_mps2] * 2 + [lim.angular_acceleration_radps2],
                       [lim.jerk_mps3] * 2 + [lim.angular_jerk_radps3]])
    ratios = [np.abs(d).max(axis=0) / b for d, b in zip((vel, acc, jerk), bounds)]
    rim = max(np.abs(wheel_rim_speeds(th, v, ROBOT)).max() for th, v in zip(theta, vel))
    return max(max(r.max() for r in ratios), rim / lim.rim_speed_mps)


def test_nominal_rim_speed_is_the_motor_speed_at_the_rim():
    assert nominal_rim_speed(ROBOT) == pytest.approx(3600.0 / 60.0 * 2.0 * math.pi / 16.0 * 0.040)


def test_rest_to_rest_motion_is_the_septic_law_and_ends_exactly_at_the_goal():
    start, goal = np.array([0.1, -0.2, 0.3]), np.array([0.6, 0.1, -0.4])
    motion = PolynomialMotion.within(np.vstack((start, np.zeros((3, 3)))), goal, limits())
    T = motion.duration_s
    t = np.linspace(0.0, T, 501)
    p = motion.evaluate(t)[0]
    s = septic(t / T)[0]
    np.testing.assert_allclose(p, start + np.outer(s, goal - start), atol=1e-12)
    end = motion.evaluate(np.array([T, T + 5.0]))
    np.testing.assert_allclose(end[0], [goal, goal], atol=1e-12)
    np.testing.assert_allclose(end[1:], 0.0, atol=1e-9)


@pytest.mark.parametrize("lim", [limits(), limits(rim_speed_mps=0.3), limits(jerk_mps3=0.5)],
                         ids=["default", "rim-bound", "jerk-bound"])
def test_motion_is_within_the_limits_and_the_shortest_such(lim: MotionLimits):
    rest = np.zeros((4, 3))
    goal = np.array([0.8, 0.5, 2.0])
    motion = PolynomialMotion.within(rest, goal, lim)
    t = np.linspace(0.0, motion.duration_s, 4001)
    p, v, a, j = motion.evaluate(t)
    assert usage(p[:, 2], v, a, j, lim) <= 1.0 + 1e-6
    shorter = PolynomialMotion(rest, goal, 0.97 * motion.duration_s)
    p, v, a, j = shorter.evaluate(t * 0.97)
    assert usage(p[:, 2], v, a, j, lim) > 1.0  # 3 % faster breaks a limit: the planner did not waste time


def test_rim_speed_limit_binds_when_it_is_the_tightest():
    lim = limits(velocity_mps=2.0, acceleration_mps2=2.0, jerk_mps3=20.0, angular_velocity_radps=10.0,
                 angular_acceleration_radps2=10.0, angular_jerk_radps3=80.0, rim_speed_mps=0.5)
    motion = PolynomialMotion.within(np.zeros((4, 3)), np.array([1.0, 0.0, 3.0]), lim)
    t = np.linspace(0.0, motion.duration_s, 3001)
    p, v, _, _ = motion.evaluate(t)
    rim = max(np.abs(wheel_rim_speeds(th, vv, ROBOT)).max() for th, vv in zip(p[:, 2], v))
    assert 0.49 < rim <= 0.5 * (1.0 + 1e-6)


def test_analytic_derivatives_match_finite_differences():
    ref = GoalReference()
    ref.go_to(0.5, np.array([0.4, -0.3, 1.0]), limits())
    t = np.linspace(0.0, ref.duration_s, 20001)
    h = t[1] - t[0]
    samples = ref.sample(t)
    for k in range(3):
        fd = np.gradient(samples[k], h, axis=0)
        np.testing.assert_allclose(fd[2:-2], samples[k + 1][2:-2], atol=5e-3 * max(1.0, np.abs(samples[k + 1]).max()))


def test_new_goal_mid_motion_takes_over_without_a_jump():
    ref = GoalReference()
    ref.go_to(1.0, np.array([0.5, 0.2, 1.0]), limits())
    before = [np.array(x) for x in ref.sample(np.array([2.0, 2.0 + 1e-9]))]
    ref.go_to(2.0, np.array([-0.3, 0.4, -1.0]), limits())
    t = np.array([2.0 - 1e-7, 2.0, 2.0 + 1e-7])
    after = ref.sample(t)
    for k in range(4):  # p, v, a, j equal the old motion's at the switch and continuous across it
        np.testing.assert_allclose(after[k][1], before[k][0], atol=1e-9)
        np.testing.assert_allclose(after[k][0], after[k][2], atol=1e-5 * max(1.0, np.abs(after[k + 1]).max())
                                   if k < 3 else 1e-3)
    # a finite difference of the positions across the switch gives the velocity there (no kink)
    fd = (after[0][2] - after[0][0]) / 2e-7
    np.testing.assert_allclose(fd, after[1][1], atol=1e-5)
    end = ref.state(ref.duration_s + 1.0)
    np.testing.assert_allclose(end[0], [-0.3, 0.4, -1.0], atol=1e-12)
    np.testing.assert_allclose(end[1:], 0.0, atol=1e-9)


def test_hold_before_goals_and_preview_protocol():
    ref = GoalReference(start=(0.2, 0.1, 0.5))
    np.testing.assert_array_equal(preview(ref, 3.0, 0.01, 4), np.tile([0.2, 0.1, 0.5], (4, 1)))
    ref.go_to(1.0, np.array([0.5, 0.1, 0.5]), limits())
    pos = ref.sample(1.5 + 0.01 * np.arange(1, 5))[0]
    np.testing.assert_allclose(preview(ref, 1.5, 0.01, 4), pos, atol=1e-12)


@pytest.mark.parametrize("goal", [[math.nan, 0.0, 0.0], [0.0, math.inf, 0.0], [0.0, 0.0]])
def test_bad_goal_is_refused_and_the_reference_unchanged(goal):
    ref = GoalReference()
    ref.go_to(0.0, np.array([0.3, 0.0, 0.0]), limits())
    t = np.linspace(0.0, 10.0, 101)
    before = ref.sample(t)
    with pytest.raises(GoalError):
        ref.go_to(1.0, goal, limits())
    for x, y in zip(before, ref.sample(t)):
        np.testing.assert_array_equal(x, y)


def test_bad_limits_and_times_are_refused():
    with pytest.raises(GoalError, match="velocity_mps"):
        limits(velocity_mps=0.0)
    with pytest.raises(GoalError, match="rim_speed_mps"):
        limits(rim_speed_mps=math.nan)
    with pytest.raises(GoalError, match="start time"):
        GoalReference().go_to(math.nan, np.zeros(3), limits())


def test_goal_at_the_resting_pose_is_no_motion():
    ref = GoalReference(start=(0.1, 0.2, 0.3))
    assert ref.go_to(2.0, np.array([0.1, 0.2, 0.3]), limits()) is None
    np.testing.assert_array_equal(ref.position(5.0), [0.1, 0.2, 0.3])


def test_braking_from_cruise_is_the_quintic_stop_within_the_limits():
    # Truth: from (p, v, 0, 0) the stop's velocity is v (1 - q(t / T)), q = 10 tau^3 - 15 tau^4 + 6 tau^5, and the
    # shortest T under |a| <= a_max, |j| <= j_max is max(15 v / (8 a_max), sqrt(10 v / (sqrt(3) j_max))) (q' peaks
    # at 15/8, q'' at 10/sqrt(3)); the planner keeps 0.998 of the limits (on a grid) and finds T to 0.2 %
    lim = limits()
    for v in (0.05, 0.2, 0.39):
        state = np.zeros((4, 3))
        state[0], state[1, 0] = (0.3, -0.1, 0.4), v
        motion = BrakingMotion.stopping(state, lim)
        T = max(15.0 * v / (8.0 * lim.acceleration_mps2), math.sqrt(10.0 * v / math.sqrt(3.0) / lim.jerk_mps3))
        assert T <= motion.duration_s <= T / 0.998 * 1.0025
        tau = np.linspace(0.0, 1.0, 401)
        p, vel, acc, jerk = motion.evaluate(tau * motion.duration_s)
        q = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        np.testing.assert_allclose(vel[:, 0], v * (1.0 - q), atol=1e-12)
        np.testing.assert_allclose(vel[:, 1:], 0.0, atol=1e-12)
        np.testing.assert_allclose(motion.goal, state[0] + [v * motion.duration_s / 2.0, 0.0, 0.0], atol=1e-12)
        assert usage(p[:, 2], vel, acc, jerk, lim) <= 1.0 + 1e-9


def test_stop_takes_over_mid_motion_without_a_jump_and_rests():
    lim = limits()
    ref = GoalReference()
    ref.go_to(0.0, np.array([1.0, 0.6, 1.2]), lim)
    switch = 1.1
    before = ref.state(switch)
    assert np.abs(before[2]).max() > 0.05  # accelerating: the stop starts from a full state
    piece = ref.stop(switch, lim)
    np.testing.assert_allclose(ref.state(switch), before, atol=1e-12)
    t = np.linspace(switch, switch + piece.duration_s, 4001)
    p, v, a, j = ref.sample(t)
    assert usage(p[:, 2], v, a, j, lim) <= 1.0 + 1e-9
    h = t[1] - t[0]
    for k, d in enumerate((v, a, j)):
        np.testing.assert_allclose(np.gradient((p, v, a)[k], h, axis=0)[2:-2], d[2:-2], atol=2e-3)
    end = ref.state(switch + piece.duration_s + 1.0)
    np.testing.assert_allclose(end[0], piece.goal, atol=1e-12)
    np.testing.assert_allclose(end[1:], 0.0, atol=1e-12)
    assert ref.stop(switch + piece.duration_s + 2.0, lim) is None  # at rest: nothing to brake


def test_a_shift_moves_the_end_eased_in_without_a_jump_and_nests():
    lim = limits()
    ref = GoalReference()
    ref.go_to(0.0, np.array([1.2, 0.4, 0.5]), lim)
    end_before = ref.duration_s
    shifts = [(1.0, np.array([0.03, -0.02, 0.05])), (2.5, np.array([-0.01, 0.04, 0.0]))]
    for t, delta in shifts:
        before = ref.state(t)
        piece = ref.shift(t, delta, lim)
        np.testing.assert_allclose(ref.state(t), before, atol=1e-12)  # p, v, a, j continuous at the switch
    assert len(piece.shifts) == 2 and not isinstance(piece.base, type(piece))  # one level: the shifts listed
    assert ref.duration_s == pytest.approx(end_before)  # eased in over the time left: not retimed
    end = ref.state(ref.duration_s + 1.0)
    np.testing.assert_allclose(end[0], [1.2 + 0.02, 0.4 + 0.02, 0.55], atol=1e-12)
    np.testing.assert_allclose(end[1:], 0.0, atol=1e-12)
    t = np.linspace(1.0, ref.duration_s, 20001)
    p, v, a, j = ref.sample(t)
    assert usage(p[:, 2], v, a, j, lim) <= 1.0 + SHIFT_SHARE
    h = t[1] - t[0]
    for k, d in enumerate((v, a, j)):
        np.testing.assert_allclose(np.gradient((p, v, a)[k], h, axis=0)[2:-2], d[2:-2], atol=5e-3)


def test_a_far_shift_takes_its_own_time_and_bad_shifts_are_refused():
    lim = limits()
    ref = GoalReference()
    ref.go_to(0.0, np.array([1.2, 0.0, 0.0]), lim)
    piece = ref.shift(ref.duration_s - 0.2, np.array([0.0, 2.0, 0.0]), lim)  # 2 m at the end: eased in over its own
    T = piece.shifts[-1][2]                                                    # time, a quarter of the limits
    _, s1, s2, s3 = septic(np.linspace(0.0, 1.0, 100001))
    least = max(2.0 * np.abs(s1).max() / (SHIFT_SHARE * lim.velocity_mps),
                (2.0 * np.abs(s2).max() / (SHIFT_SHARE * lim.acceleration_mps2)) ** 0.5,
                (2.0 * np.abs(s3).max() / (SHIFT_SHARE * lim.jerk_mps3)) ** (1 / 3))
    assert T == pytest.approx(least, rel=1e-3)
    t = np.linspace(0.0, ref.duration_s, 20001)
    p, v, a, j = ref.sample(t)
    assert usage(p[:, 2], v, a, j, lim) <= 1.0 + SHIFT_SHARE
    np.testing.assert_allclose(ref.position(ref.duration_s), [1.2, 2.0, 0.0], atol=1e-12)
    before = ref.sample(t)
    for bad in ((0.0, np.zeros(3), GoalReference()), (1.0, np.array([math.nan, 0.0, 0.0]), ref)):
        with pytest.raises(GoalError):
            bad[2].shift(bad[0], bad[1], lim)  # nothing runs to shift; a non-finite shift
    for x, y in zip(before, ref.sample(t)):
        np.testing.assert_array_equal(x, y)
