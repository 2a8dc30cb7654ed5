"""C^3 references: derivatives vs finite differences, joints, scenario geometry, preview, errors."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.reference.trajectories import (
    REFERENCES,
    PointToPointReference,
    TrajectoryError,
    make_reference,
    preview,
    preview_at,
    septic,
    shift_preview,
)

pytestmark = pytest.mark.unit

H = 1e-5  # finite-difference step [s]


def references():
    return [make_reference(name) for name in REFERENCES]


def joints(ref):
    """Times where the reference switches pieces (ramp ends, segment ends), plus start and end."""
    if isinstance(ref, PointToPointReference):
        return np.concatenate(([0.0], ref.arrival_times_s, ref.arrival_times_s + 1.0))
    return np.array([0.0, 2.0, ref.duration_s - 2.0, ref.duration_s])  # default ramp_s = 2 s


@pytest.mark.parametrize("ref", references(), ids=REFERENCES)
def test_derivatives_match_central_differences(ref):
    t = np.linspace(-0.5, ref.duration_s + 0.5, 4001)
    d = ref.sample(t)
    for order in range(3):
        fd = (ref.sample(t + H)[order] - ref.sample(t - H)[order]) / (2 * H)
        np.testing.assert_allclose(fd, d[order + 1], rtol=0, atol=2e-7)
    assert np.abs(d[1]).max() > 0.1  # not trivially zero


@pytest.mark.parametrize("ref", references(), ids=REFERENCES)
def test_scalar_path_agrees_with_differences_and_arrays(ref):
    # The scalar backend (used each control tick) is checked on its own, off the joints
    # (where the snap jumps and central differences of the acceleration lose an order).
    for t in np.linspace(0.0123, ref.duration_s - 0.0123, 37):
        d = ref.sample(float(t))
        assert all(v.shape == (3,) for v in d)
        for order in range(3):
            fd = (ref.sample(float(t) + H)[order] - ref.sample(float(t) - H)[order]) / (2 * H)
            np.testing.assert_allclose(fd, d[order + 1], rtol=0, atol=2e-7)
        rows = ref.sample(np.array([t]))
        for a, b in zip(d, rows):
            np.testing.assert_allclose(a, b[0], rtol=0, atol=1e-13)
        np.testing.assert_allclose(ref.position(float(t)), d[0], rtol=0, atol=1e-15)


@pytest.mark.parametrize("ref", references(), ids=REFERENCES)
def test_jerk_is_continuous_at_every_joint(ref):
    eps = 1e-7
    for t in joints(ref):
        left, right = ref.sample(t - eps), ref.sample(t + eps)
        for order in (1, 2, 3):
            np.testing.assert_allclose(left[order], right[order], rtol=0, atol=1e-4)


@pytest.mark.parametrize("ref", references(), ids=REFERENCES)
def test_starts_and_ends_at_rest_at_the_origin(ref):
    for t in (0.0, -1.0, ref.duration_s, ref.duration_s + 3.0):
        pos, vel, acc, jerk = ref.sample(t)
        np.testing.assert_allclose(pos, 0.0, atol=1e-12)
        for value in (vel, acc, jerk):
            np.testing.assert_allclose(value, 0.0, atol=1e-12)


def test_paper_circle_geometry():
    ref = make_reference("paper-circle")
    assert ref.duration_s == pytest.approx(2 * 10.0 + 2.0)
    t = np.linspace(2.0, ref.duration_s - 2.0, 2001)  # full speed
    pos, vel, acc, _ = ref.sample(t)
    np.testing.assert_allclose(np.hypot(pos[:, 0], pos[:, 1] - 0.5), 0.5, atol=1e-12)
    np.testing.assert_allclose(np.hypot(vel[:, 0], vel[:, 1]), 2 * np.pi * 0.5 / 10.0, atol=1e-12)
    np.testing.assert_allclose(np.hypot(acc[:, 0], acc[:, 1]), 0.5 * (2 * np.pi / 10.0) ** 2, atol=1e-12)
    t_lap = t[t < ref.duration_s - 12.0]
    np.testing.assert_allclose(ref.position(t_lap + 10.0), ref.position(t_lap), atol=1e-12)
    whole = ref.sample(np.linspace(0.0, ref.duration_s, 20001))
    np.testing.assert_array_equal(whole[0][:, 2], 0.0)  # theta_d = 0 throughout
    assert np.hypot(whole[2][:, 0], whole[2][:, 1]).max() < 0.4  # modest ramp accelerations


def test_lemniscate_heading_follows_the_velocity():
    ref = make_reference("lemniscate")
    t = np.linspace(0.0, ref.duration_s, 40001)
    pos, vel, _, _ = ref.sample(t)
    moving = np.hypot(vel[:, 0], vel[:, 1]) > 1e-9
    assert moving.sum() > 39000
    diff = np.angle(np.exp(1j * (pos[moving, 2] - np.arctan2(vel[moving, 1], vel[moving, 0]))))
    np.testing.assert_allclose(diff, 0.0, atol=1e-9)
    # Continuous (no 2 pi jumps) and turning both ways, as a figure-eight does.
    assert np.abs(np.diff(pos[:, 2])).max() < 1e-3
    assert np.ptp(pos[:, 2]) > np.pi
    # 1 m wide, 0.5 m high.
    assert np.ptp(pos[:, 0]) == pytest.approx(1.0, abs=1e-6)
    assert np.ptp(pos[:, 1]) == pytest.approx(0.5, abs=1e-6)


def test_point_to_point_reaches_each_waypoint_at_rest():
    ref = make_reference("point-to-point")
    wp = ref.waypoints
    steps = np.diff(np.vstack((ref.start, wp)), axis=0)
    pure_rotation = (np.hypot(steps[:, 0], steps[:, 1]) == 0) & (steps[:, 2] != 0)
    diagonal = (steps[:, 0] != 0) & (steps[:, 1] != 0)
    assert pure_rotation.any() and diagonal.any()
    for t, target in zip(ref.arrival_times_s, wp):
        for tt in (t, t + 0.5):  # arrival and dwell
            pos, vel, acc, jerk = ref.sample(tt)
            np.testing.assert_allclose(pos, target, atol=1e-12)
            np.testing.assert_allclose(np.concatenate((vel, acc, jerk)), 0.0, atol=1e-12)
    vel = ref.sample(np.linspace(0.0, ref.duration_s, 20001))[1]
    assert np.hypot(vel[:, 0], vel[:, 1]).max() <= 0.25 + 1e-9
    assert np.abs(vel[:, 2]).max() <= 0.8 + 1e-9


def test_septic_law():
    tau = np.linspace(0.0, 1.0, 2001)
    s = septic(tau)
    np.testing.assert_allclose([v[0] for v in s], [0, 0, 0, 0], atol=0)
    np.testing.assert_allclose([v[-1] for v in s], [1, 0, 0, 0], atol=1e-12)
    h = 1e-6
    for k in range(3):
        fd = (septic(tau + h)[k] - septic(tau - h)[k]) / (2 * h)
        np.testing.assert_allclose(fd[1:-1], s[k + 1][1:-1], atol=1e-5)
    assert s[1].max() == pytest.approx(35 / 16)


waypoint = st.tuples(
    st.floats(-2, 2, allow_nan=False), st.floats(-2, 2, allow_nan=False), st.floats(-4, 4, allow_nan=False)
)


@settings(max_examples=40, deadline=None)
@given(
    wps=st.lists(waypoint, min_size=1, max_size=5),
    dwell=st.sampled_from([0.0, 0.3, 1.0]),
    segment=st.one_of(st.none(), st.floats(0.2, 5.0)),
)
def test_random_waypoints_rest_to_rest(wps, dwell, segment):
    ref = PointToPointReference(wps, dwell_s=dwell, segment_s=segment)
    poses = np.vstack(((0.0, 0.0, 0.0), np.array(wps)))
    starts = np.concatenate(([0.0], ref.arrival_times_s[:-1] + dwell))
    for k, (t0, t1) in enumerate(zip(starts, ref.arrival_times_s)):
        for t, target in ((t0, poses[k]), (t1, poses[k + 1])):
            pos, vel, acc, jerk = ref.sample(t)
            np.testing.assert_allclose(pos, target, atol=1e-9)
            np.testing.assert_allclose(np.concatenate((vel, acc, jerk)), 0.0, atol=1e-9)
        # In between: on the straight line between the two poses, moving forward only.
        t = np.linspace(t0, t1, 11)
        pos, vel = ref.sample(t)[:2]
        step = poses[k + 1] - poses[k]
        progress = (pos - poses[k]) @ step / max(step @ step, 1e-300)
        np.testing.assert_allclose(pos, poses[k] + np.outer(progress, step), atol=1e-9)
        assert np.all(vel @ step >= -1e-12)
    assert ref.duration_s == pytest.approx(ref.arrival_times_s[-1] + dwell)


def test_preview_positions_and_hold():
    for ref in references():
        for t in (0.0, 3.3, ref.duration_s - 0.02):
            got = preview(ref, t, 0.01, 4)
            assert got.shape == (4, 3)
            np.testing.assert_allclose(got, ref.position(t + 0.01 * np.arange(1, 5)), atol=1e-13)
        np.testing.assert_allclose(preview(ref, ref.duration_s + 5.0, 0.01, 3), 0.0, atol=1e-12)


def test_shift_preview_moves_points_in_time_to_the_taylor_bound():
    """Against the reference sampled at the shifted times: error <= max|jerk| |dt|^3 / 6 (+ rounding)."""
    Ts, N = 0.01, 4
    for ref in references():
        for t in np.linspace(0.0, ref.duration_s, 37):
            pos, vel, acc, _ = ref.sample(t + Ts * np.arange(N + 1))
            for dt in (-0.01, -0.004, 0.003, 0.0099):
                exact = ref.position(t + dt + Ts * np.arange(N + 1))
                window = t + Ts * np.arange(N + 1)[:, None] + np.linspace(min(dt, 0.0), max(dt, 0.0), 21)
                jerk = np.abs(ref.sample(window.ravel())[3]).reshape(N + 1, 21, 3).max(axis=1)
                bound = jerk * abs(dt) ** 3 / 6.0 + 1e-12
                assert np.all(np.abs(shift_preview(pos, vel, acc, dt) - exact) <= bound)
            np.testing.assert_array_equal(shift_preview(pos, vel, acc, 0.0), pos)


def test_preview_at_takes_the_rows_of_the_periods_elapsed_then_the_taylor_step():
    """A preview of N + 1 + extra points at t_p, asked at t_p + g: rows m = min(g // Ts, extra) .. m + N of the
    reference sampled at t_p + j Ts, moved by g - m Ts within the Taylor bound of that remainder; a preview of
    exactly N + 1 points (or a stamp before the preview's) is `shift_preview` by g, bit for bit.
    """
    Ts, Ts_ns, N, extra, t_p = 0.01, 10_000_000, 4, 9, 2_000_000_000
    for ref in references():
        for start in np.linspace(0.0, ref.duration_s, 13):
            t0 = t_p + round(start * 1e9)
            pos, vel, acc, _ = ref.sample(t0 * 1e-9 + Ts * np.arange(N + 1 + extra))
            for gap in (-3_000_000, 0, 4_000_000, 30_000_000, 93_000_000, 140_000_000):
                got, got_vel, got_acc = preview_at(t0 + gap, t0, pos, vel, acc, Ts_ns, N + 1)
                m = min(max(gap // Ts_ns, 0), extra)
                dt = (gap - m * Ts_ns) * 1e-9
                exact = ref.sample(t0 * 1e-9 + gap * 1e-9 + Ts * np.arange(N + 1))
                window = (t0 * 1e-9 + m * Ts + Ts * np.arange(N + 1)[:, None]
                          + np.linspace(min(dt, 0.0), max(dt, 0.0), 21))
                jerk = np.abs(ref.sample(window.ravel())[3]).reshape(N + 1, 21, 3).max(axis=1)
                assert got.shape == (N + 1, 3) and np.all(np.abs(got - exact[0]) <= jerk * abs(dt) ** 3 / 6 + 1e-12)
                assert np.all(np.abs(got_vel - exact[1]) <= jerk * dt * dt / 2 + 1e-12)
                np.testing.assert_array_equal(got_acc, acc[m:m + N + 1])
                short = preview_at(t0 + gap, t0, pos[:N + 1], vel[:N + 1], acc[:N + 1], Ts_ns, N + 1)[0]
                np.testing.assert_array_equal(short, shift_preview(pos[:N + 1], vel[:N + 1], acc[:N + 1], gap * 1e-9))


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: make_reference("square"), "paper-circle, lemniscate, point-to-point"),
        (lambda: make_reference("robustness"), "unknown reference 'robustness'"),  # a scenario, not a reference
        (lambda: make_reference("paper-circle", radius_m=-0.5), "radius_m"),
        (lambda: make_reference("paper-circle", radius=0.5), "radius"),
        (lambda: make_reference("paper-circle", ramp_s=30.0), "ramp_s"),
        (lambda: make_reference("lemniscate", period_s=float("nan")), "period_s"),
        (lambda: make_reference("point-to-point", waypoints=[(0.0, float("nan"), 0.0)]), "waypoints"),
        (lambda: make_reference("point-to-point", waypoints=[(1.0, 2.0)]), "waypoints"),
        (
            lambda: make_reference("point-to-point", waypoints=[(1, 2, 3), (4, 5, 6)], segment_s=[1, 2, 3]),
            "segment_s",
        ),
        (lambda: make_reference("point-to-point", dwell_s=-1.0), "dwell_s"),
        (lambda: make_reference("point-to-point", waypoints=[(1, 2, 3), (1, 2)]), "waypoints"),
        (lambda: make_reference("paper-circle").sample(float("nan")), "t"),
        (lambda: make_reference("paper-circle").sample(np.zeros((2, 2))), "t"),
        (lambda: preview(make_reference("paper-circle"), 0.0, 0.01, 0), "horizon"),
        (lambda: preview(make_reference("paper-circle"), 0.0, -0.01, 4), "period_s"),
        (lambda: preview(make_reference("paper-circle"), math.inf, 0.01, 4), "t"),
    ],
)
def test_bad_input_raises(call, match):
    with pytest.raises(TrajectoryError, match=match):
        call()
