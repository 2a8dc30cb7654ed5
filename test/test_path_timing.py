"""Timed planner paths (reference.path_timing, through reference.goals) against independent truths.

Truths: the path's poses (the trajectory passes through each and rests at the last), finite differences
of the sampled positions (the analytic derivatives, C^3), dense resampling with
`model.dynamics.wheel_rim_speeds` (the limits), and the reference state before a switch (continuity).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_goal_motion import limits, usage

from robotino_geom_mpc.reference.goal_motion import GoalError
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.reference.time_law import septic

pytestmark = pytest.mark.unit

POSES = np.array([[0.3, 0.0, 0.0], [0.6, 0.3, 0.8], [0.6, 0.6, 1.6], [0.3, 0.6, 1.6], [0.0, 0.3, 0.5]])


def _dense(ref: GoalReference, t0: float, n: int = 20001):
    t = np.linspace(t0, ref.duration_s, n)
    return t, ref.sample(t)


def test_path_passes_through_every_pose_and_rests_at_the_last():
    ref = GoalReference()
    ref.follow(1.0, POSES, limits())
    t, (p, _, _, _) = _dense(ref, 1.0, 40001)
    for pose in POSES:
        assert np.linalg.norm(p - pose, axis=1).min() < 1e-3
    end = ref.state(ref.duration_s + 2.0)
    np.testing.assert_allclose(end[0], POSES[-1], atol=1e-12)
    np.testing.assert_allclose(end[1:], 0.0, atol=1e-9)


@pytest.mark.slow
def test_path_keeps_the_limits_and_is_c3():
    lim = limits()
    ref = GoalReference()
    piece = ref.follow(0.0, POSES, lim)
    t, samples = _dense(ref, 0.0)
    assert usage(samples[0][:, 2], *samples[1:], lim) <= 1.0 + 1e-6
    assert usage(samples[0][:, 2], *samples[1:], lim) > 0.9  # and uses them (the timing is not slack)
    h = t[1] - t[0]
    for k in range(3):
        fd = np.gradient(samples[k], h, axis=0)
        np.testing.assert_allclose(fd[2:-2], samples[k + 1][2:-2], atol=5e-3 * max(1.0, np.abs(samples[k + 1]).max()))
    # at rest (v, a, j = 0) at both ends
    for tk in (0.0, piece.duration_s):
        np.testing.assert_allclose(ref.state(tk)[1:], 0.0, atol=1e-9)


def test_path_from_a_moving_reference_blends_without_a_jump():
    ref = GoalReference()
    ref.go_to(0.0, np.array([1.0, 0.5, 1.0]), limits())
    switch = 1.3
    old = ref.state(switch)
    assert np.abs(old[1]).max() > 0.1  # moving
    piece = ref.follow(switch, POSES, limits())
    assert piece.blend is not None
    np.testing.assert_allclose(ref.state(switch), old, atol=1e-9)
    eps = 1e-7
    left, right = ref.state(switch - eps), ref.state(switch + eps)
    np.testing.assert_allclose(left[:3], right[:3], atol=1e-5)
    t, samples = _dense(ref, switch)
    h = t[1] - t[0]
    for k in range(3):
        fd = np.gradient(samples[k], h, axis=0)
        np.testing.assert_allclose(fd[2:-2], samples[k + 1][2:-2], atol=5e-3 * max(1.0, np.abs(samples[k + 1]).max()))
    np.testing.assert_allclose(ref.position(ref.duration_s), POSES[-1], atol=1e-12)


def test_rotation_in_place_and_duplicate_poses():
    ref = GoalReference(start=(0.2, 0.1, 0.0))
    ref.follow(0.0, [[0.2, 0.1, 0.0], [0.2, 0.1, 1.0], [0.2, 0.1, 1.0], [0.2, 0.1, -0.5]], limits())
    t, (p, v, a, j) = _dense(ref, 0.0, 4001)
    np.testing.assert_allclose(p[:, :2], np.tile([0.2, 0.1], (len(t), 1)), atol=1e-9)
    assert np.abs(p[:, 2] - 1.0).min() < 1e-3  # through the middle pose (a quintic may overshoot it a little)
    assert usage(p[:, 2], v, a, j, limits()) <= 1.0 + 1e-6
    np.testing.assert_allclose(ref.position(ref.duration_s), [0.2, 0.1, -0.5], atol=1e-12)


def test_single_pose_path_is_a_straight_move():
    ref = GoalReference()
    ref.follow(0.0, [[0.5, 0.5, 0.0]], limits())
    t, (p, _, _, _) = _dense(ref, 0.0, 2001)
    np.testing.assert_allclose(p[:, 0], p[:, 1], atol=1e-12)  # on the diagonal
    np.testing.assert_allclose(ref.position(ref.duration_s), [0.5, 0.5, 0.0], atol=1e-12)


@pytest.mark.parametrize("poses", [np.zeros((0, 3)), [[0.1, math.nan, 0.0]], [[0.1, 0.2]]],
                         ids=["empty", "nan", "shape"])
def test_bad_paths_are_refused_and_the_reference_unchanged(poses):
    ref = GoalReference()
    ref.go_to(0.0, np.array([0.3, 0.0, 0.0]), limits())
    t = np.linspace(0.0, 10.0, 101)
    before = ref.sample(t)
    with pytest.raises(GoalError):
        ref.follow(1.0, poses, limits())
    for x, y in zip(before, ref.sample(t)):
        np.testing.assert_array_equal(x, y)


def test_a_corner_is_passed_at_rest_and_a_long_leg_cruises_at_the_speed_limit():
    # a planner's 90 degree corner, poses 5 cm apart, heading fixed: two straight legs joined at rest at the corner
    s = np.arange(0.0, 1.5001, 0.05)
    poses = np.vstack((np.column_stack((s, 0 * s, 0 * s)), np.column_stack((1.5 + 0 * s[1:], s[1:], 0 * s[1:]))))
    lim = limits()
    ref = GoalReference()
    piece = ref.follow(0.0, poses, lim)
    assert len(piece.segments) == 2
    t, (p, v, a, j) = _dense(ref, 0.0, 30001)
    assert usage(p[:, 2], v, a, j, lim) <= 1.0 + 1e-6
    corner = np.argmin(np.hypot(p[:, 0] - 1.5, p[:, 1]))
    assert np.hypot(*(p[corner, :2] - [1.5, 0.0])) < 1e-9 and np.abs(v[corner]).max() < 1e-6  # through it, at rest
    first_leg = t < piece.starts[1]
    assert np.abs(p[first_leg, 1]).max() < 1e-9  # straight: the corner does not ring back into the leg
    speed = v[first_leg, 0]
    assert np.mean(speed >= 0.999 * speed.max()) > 0.2  # it cruises: a plateau (one septic over the leg has none)
    # Truth for the leg's duration: a rate r ramped in and out over T_r by the septic smoothstep s covers L in
    # L / r + T_r, with T_r >= max s' r / a_max and T_r >= sqrt(max s'' r / j_max), r <= v_max; the best r on a grid
    tau = np.linspace(0.0, 1.0, 100001)
    _, s1, s2, _ = septic(tau)
    rates = np.linspace(0.01, lim.velocity_mps, 4000)
    ramp = np.maximum(s1.max() * rates / lim.acceleration_mps2, np.sqrt(np.abs(s2).max() * rates / lim.jerk_mps3))
    best = float(np.min(1.5 / rates + ramp))
    leg = piece.segments[0].duration_s
    print(f"leg of 1.5 m: {leg:.3f} s, the best ramped cruise {best:.3f} s")
    assert best * 0.999 <= leg <= 1.1 * best
