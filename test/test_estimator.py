"""Odometry filter against independent truths: Lyapunov variance, exact tracks, the Kalman DARE, heading wrap."""

import math

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov

from robotino_geom_mpc.control.estimator import EstimatorError, OdometryFilter, filter_gain, noise_std_ratio
from robotino_geom_mpc.control.mpc import discretize_axis

pytestmark = pytest.mark.unit

TS = 0.01


def _run(filt, states):
    """Feed rows (x, x', y, y', theta, theta') and return the estimates, shape (n, 3)."""
    return np.array([filt.update(*row) for row in states.tolist()])


def _track(n, pos0, vel, acc=(0.0, 0.0, 0.0)):
    """Constant-acceleration track sampled at k Ts: rows (x, x', y, y', theta, theta')."""
    t = np.arange(n)[:, None] * TS
    pos = np.asarray(pos0) + np.asarray(vel) * t + 0.5 * np.asarray(acc) * t**2
    v = np.asarray(vel) + np.asarray(acc) * t
    return np.column_stack((pos[:, 0], v[:, 0], pos[:, 1], v[:, 1], pos[:, 2], v[:, 2])), pos


@pytest.mark.parametrize("tau", [0.05, 0.5])
def test_white_pose_noise_is_reduced_to_the_steady_state_variance(tau):
    """Estimate error = AR(1) e(k) = (1 - L) e(k-1) + L n(k): its variance from the discrete Lyapunov equation."""
    n, sigma = 200_000, (1e-3, 2e-3, 1e-3)
    states, truth = _track(n, (0.1, -0.2, 0.3), (0.3, -0.1, 0.5))
    noise = np.random.default_rng(7).normal(0.0, sigma, (n, 3))
    noisy = states.copy()
    noisy[:, 0::2] += noise
    filt = OdometryFilter(TS, tau)
    error = _run(filt, noisy) - truth
    L = 1.0 - math.exp(-TS / tau)
    burn = int(20 * tau / TS)
    for axis in range(3):
        expected_var = solve_discrete_lyapunov(np.array([[1.0 - L]]), np.array([[L**2 * sigma[axis] ** 2]]))[0, 0]
        assert np.std(error[burn:, axis]) == pytest.approx(math.sqrt(expected_var), rel=0.04)
        assert np.mean(error[burn:, axis]) == pytest.approx(0.0, abs=0.1 * math.sqrt(expected_var))
    assert noise_std_ratio(filt.gain) == pytest.approx(math.sqrt(expected_var) / sigma[2], rel=1e-12)


def test_gain_is_the_steady_state_kalman_gain_of_the_random_walk_model():
    """p(k) = p(k-1) + Ts v + w, z = p + n with var w / var n = L^2 / (1 - L): DARE gives the same L."""
    for tau in (0.05, 0.5, 3.0):
        L = OdometryFilter(TS, tau).gain
        r = 1e-6
        q = r * L**2 / (1.0 - L)
        P = solve_discrete_are(np.eye(1), np.eye(1), np.array([[q]]), np.array([[r]]))[0, 0]  # prior covariance
        assert P / (P + r) == pytest.approx(L, rel=1e-9)
        assert L == pytest.approx(TS / tau, rel=TS / tau)  # first-order lag: L ~ Ts / tau


def test_constant_acceleration_track_is_followed_without_bias():
    states, truth = _track(3000, (1.0, -2.0, 3.0), (0.4, -0.3, 1.5), (0.5, 0.2, -0.7))
    filt = OdometryFilter(TS, 0.5)
    np.testing.assert_allclose(_run(filt, states), truth, rtol=0, atol=1e-12)


def test_friction_axis_error_stays_within_the_trapezoid_bound():
    """ZOH axis of eq. (49) with friction and random inputs: |error| <= (Ts^3 / 12) max|v''| (1 - L) / L."""
    damping, tau, n = 5.0, 0.5, 2000
    A_d, B_d = discretize_axis(damping, TS)
    u = np.random.default_rng(3).uniform(-2.0, 2.0, n)
    x = np.zeros((n, 2))
    x[0] = (0.2, 0.1)
    for k in range(1, n):
        x[k] = A_d @ x[k - 1] + B_d * u[k - 1]
    states = np.column_stack((x[:, 0], x[:, 1], x[:, 0], x[:, 1], x[:, 0], x[:, 1]))
    error = _run(OdometryFilter(TS, tau), states) - x[:, [0]]
    L = 1.0 - math.exp(-TS / tau)
    v_second = damping * (np.abs(u).max() + damping * np.abs(x[:, 1]).max())  # |v''| = d |u - d v|
    bound = TS**3 / 12.0 * v_second * (1.0 - L) / L
    assert np.abs(error).max() <= bound
    assert np.abs(error).max() > 0.01 * bound  # the bound is of the right order, not vacuous


def test_pose_step_is_followed_with_the_time_constant():
    """Robot at rest, pose jumps by d: the estimate approaches it as d (1 - exp(-t / tau)), the continuous lag."""
    tau, d = 0.3, np.array([0.01, -0.02, 0.05])
    filt = OdometryFilter(TS, tau)
    assert filt.update(0.0, 0.0, 0.0, 0.0, 0.0, 0.0) == (0.0, 0.0, 0.0)
    est = _run(filt, np.tile(np.array([d[0], 0.0, d[1], 0.0, d[2], 0.0]), (100, 1)))
    t = np.arange(1, 101)[:, None] * TS
    np.testing.assert_allclose(est, d * (1.0 - np.exp(-t / tau)), rtol=1e-12, atol=1e-15)


def test_first_measurement_initialises_and_reset_restores_it():
    states, _ = _track(50, (0.1, 0.2, 0.3), (0.2, 0.1, 0.4))
    noisy = states + np.random.default_rng(1).normal(0.0, 1e-3, states.shape)
    filt = OdometryFilter(TS, 0.5)
    assert not filt.initialized and filt.estimate is None
    first = _run(filt, noisy)
    np.testing.assert_array_equal(first[0], noisy[0, 0::2])
    filt.reset()
    assert not filt.initialized
    np.testing.assert_array_equal(_run(filt, noisy), first)


def test_measured_heading_wrapped_to_pi_leaves_the_estimate_on_its_branch():
    """theta crosses pi; the measurement wrapped to (-pi, pi] gives the same estimate as the continuous one."""
    states, truth = _track(600, (0.0, 0.0, 2.5), (0.1, 0.0, 1.5))
    states[:, 4::2] += np.random.default_rng(2).normal(0.0, 1e-3, (600, 1))
    wrapped = states.copy()
    wrapped[:, 4] = np.angle(np.exp(1j * states[:, 4]))
    assert np.abs(np.diff(wrapped[:, 4])).max() > 6.0  # the measurement does jump by 2 pi
    a = _run(OdometryFilter(TS, 0.5), states)
    b = _run(OdometryFilter(TS, 0.5), wrapped)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)
    assert truth[-1, 2] > math.pi and abs(b[-1, 2] - truth[-1, 2]) < 3e-3


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_measurement_is_rejected_without_touching_the_state(bad):
    states, _ = _track(20, (0.1, 0.2, 0.3), (0.2, 0.1, 0.4))
    filt, twin = OdometryFilter(TS, 0.5), OdometryFilter(TS, 0.5)
    _run(filt, states[:10])
    _run(twin, states[:10])
    row = states[10].tolist()
    row[3] = bad
    with pytest.raises(EstimatorError, match="measurement must be finite"):
        filt.update(*row)
    assert filt.estimate == twin.estimate
    np.testing.assert_array_equal(_run(filt, states[10:]), _run(twin, states[10:]))


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: OdometryFilter(TS, 0.0), "time_constant_s"),
        (lambda: OdometryFilter(TS, math.nan), "time_constant_s"),
        (lambda: OdometryFilter(0.0, 0.5), "period_s"),
        (lambda: filter_gain(TS, -1.0), "time_constant_s"),
        (lambda: noise_std_ratio(0.0), "gain"),
    ],
)
def test_bad_settings_raise_naming_the_argument(call, match):
    with pytest.raises(EstimatorError, match=match):
        call()


def test_zero_time_constant_means_the_raw_measurement():
    assert filter_gain(TS, 0.0) == 1.0
    assert noise_std_ratio(1.0) == 1.0


def test_velocity_bias_becomes_the_predicted_position_bias():
    """Measured velocity v + b: the fixed point of e = (1 - L)(e + b Ts) is e = b Ts (1 - L) / L."""
    tau, b = 0.5, np.array([0.003, -0.002, 0.01])
    states, truth = _track(int(30 * tau / TS), (0.0, 0.0, 0.0), (0.3, 0.1, -0.2))
    states[:, 1::2] += b
    L = 1.0 - math.exp(-TS / tau)
    error = _run(OdometryFilter(TS, tau), states)[-1] - truth[-1]
    np.testing.assert_allclose(error, b * TS * (1.0 - L) / L, rtol=1e-6)


def _irregular_times(n, seed):
    """Measurement times with intervals from 1e-9 s (a repeated tick) to 25 ms (lost ticks)."""
    steps = np.random.default_rng(seed).choice([1e-9, 0.004, 0.009, TS, 0.011, 0.021, 0.025], n - 1)
    return np.concatenate(([0.0], np.cumsum(steps))), steps


def test_irregular_intervals_follow_a_constant_acceleration_track_exactly():
    """The trapezoid over the true interval is exact for constant acceleration, whatever the spacing."""
    times, steps = _irregular_times(400, 4)
    pos0, vel, acc = np.array([1.0, -2.0, 3.0]), np.array([0.4, -0.3, 1.5]), np.array([0.5, 0.2, -0.7])
    t = times[:, None]
    pos, v = pos0 + vel * t + 0.5 * acc * t**2, vel + acc * t
    filt = OdometryFilter(TS, 0.5)
    est = [
        filt.update(pos[k, 0], v[k, 0], pos[k, 1], v[k, 1], pos[k, 2], v[k, 2], dt)
        for k, dt in enumerate([None, *steps.tolist()])
    ]
    np.testing.assert_allclose(est, pos, rtol=0, atol=1e-12)
    # told one period each time instead, the same filter drifts off the track
    filt.reset()
    wrong = [filt.update(pos[k, 0], v[k, 0], pos[k, 1], v[k, 1], pos[k, 2], v[k, 2]) for k in range(len(times))]
    assert np.abs(np.array(wrong) - pos).max() > 1e-3


def test_pose_step_is_followed_with_the_time_constant_at_irregular_intervals():
    """At rest after a pose jump d: the estimate is d (1 - exp(-t / tau)) at each measurement time t, however spaced."""
    tau, d = 0.3, np.array([0.01, -0.02, 0.05])
    times, steps = _irregular_times(100, 5)
    filt = OdometryFilter(TS, tau)
    filt.update(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    est = [filt.update(d[0], 0.0, d[1], 0.0, d[2], 0.0, float(dt)) for dt in steps]
    np.testing.assert_allclose(est, d * (1.0 - np.exp(-times[1:, None] / tau)), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("dt", [0.0, -TS, math.nan, math.inf])
def test_bad_interval_is_rejected_without_touching_the_state(dt):
    filt = OdometryFilter(TS, 0.5)
    filt.update(0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
    before = filt.estimate
    with pytest.raises(EstimatorError, match="dt_s"):
        filt.update(0.1, 0.2, 0.3, 0.0, 0.0, 0.0, dt)
    assert filt.estimate == before


def _se2_step(pose, twist_body, dt):
    """The pose after dt at a constant body twist, by the matrix exponential of se(2) (independent of the filter)."""
    from scipy.linalg import expm

    x, y, theta = pose
    vx, vy, w = twist_body
    g = np.array([[math.cos(theta), -math.sin(theta), x], [math.sin(theta), math.cos(theta), y], [0.0, 0.0, 1.0]])
    g = g @ expm(np.array([[0.0, -w, vx], [w, 0.0, vy], [0.0, 0.0, 0.0]]) * dt)
    return g[0, 2], g[1, 2], theta + w * dt


def _period_mean_rows(pose0, twists, dts):
    """Odometry as an encoder gives it: the pose at each time and the body twist held over the last interval
    (zero before the first), rotated into the odom frame with the pose's heading (eq. 2); and the true poses.
    """
    poses, twist = [tuple(pose0)], (0.0, 0.0, 0.0)
    rows = []
    for k in range(len(dts) + 1):
        if k:
            twist = tuple(twists[k - 1])
            poses.append(_se2_step(poses[-1], twist, dts[k - 1]))
        x, y, theta = poses[-1]
        c, s = math.cos(theta), math.sin(theta)
        rows.append((x, c * twist[0] - s * twist[1], y, s * twist[0] + c * twist[1], theta, twist[2]))
    return np.array(rows), np.array(poses)


@pytest.mark.parametrize("vel, acc", [((0.4, -0.3, 0.0), (0.5, -0.2, 0.0)), ((0.0, 0.0, 0.8), (0.0, 0.0, -0.7))],
                         ids=["translation", "turn_in_place"])
def test_period_mean_twist_of_a_constant_acceleration_track_is_predicted_exactly(vel, acc):
    """Constant acceleration, the twist the mean over each period: the period-mean predictor tracks the pose to
    1e-12; the trapezoid on the same twists lags by its per-period error a Ts^2 / 2, to the fixed point
    e = -(a Ts^2 / 2) (1 - L) / L of e = (1 - L)(e + prediction error).
    """
    tau, n = 0.5, 3000
    states, truth = _track(n, (1.0, -2.0, 0.3), vel, acc)
    exact = states.copy()  # instantaneous samples
    states[1:, 1::2] = np.diff(truth, axis=0) / TS  # the mean over the last period
    np.testing.assert_allclose(_run(OdometryFilter(TS, tau, "period_mean"), states), truth, rtol=0, atol=1e-12)
    L = 1.0 - math.exp(-TS / tau)
    lag = _run(OdometryFilter(TS, tau, "instantaneous"), states)[-1] - truth[-1]
    np.testing.assert_allclose(lag, -0.5 * np.array(acc) * TS**2 * (1.0 - L) / L, rtol=1e-6, atol=1e-15)
    # and the other way round: instantaneous samples, where the trapezoid is the exact one
    np.testing.assert_allclose(_run(OdometryFilter(TS, tau), exact), truth, rtol=0, atol=1e-12)
    assert np.abs(_run(OdometryFilter(TS, tau, "period_mean"), exact)[-1] - truth[-1]).max() > 1e-5


def test_period_mean_twist_while_turning_reproduces_the_dead_reckoned_pose():
    """Body twists held over irregular intervals while the robot turns (SE(2) exponential by expm): the
    period-mean predictor is that dead reckoning, so the estimate is the pose to 1e-12; the trapezoid is not.
    """
    rng = np.random.default_rng(11)
    n = 800
    twists = np.column_stack((rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n), rng.uniform(-3.0, 3.0, n)))
    dts = rng.choice([1e-9, 0.004, TS, 0.021], n)
    states, truth = _period_mean_rows((0.2, -0.1, 3.0), twists, dts)
    filt = OdometryFilter(TS, 0.5, "period_mean")
    est = [filt.update(*row, dt) for row, dt in zip(states.tolist(), [None, *dts.tolist()])]
    np.testing.assert_allclose(est, truth, rtol=0, atol=1e-12)
    trapezoid = OdometryFilter(TS, 0.5)
    est = [trapezoid.update(*row, dt) for row, dt in zip(states.tolist(), [None, *dts.tolist()])]
    assert np.abs(np.array(est)[:, :2] - truth[:, :2]).max() > 1e-4


def test_unknown_twist_model_is_refused():
    with pytest.raises(EstimatorError, match="twist must be one of instantaneous, period_mean"):
        OdometryFilter(TS, 0.5, "average")


@pytest.mark.parametrize("twist", ["instantaneous", "period_mean"])
def test_start_at_a_known_pose_is_a_filter_that_had_been_running_at_rest_there(twist):
    """start_at(s) then noisy measurements = a filter that first saw the robot at rest at s for a while: the first
    measurement's noise enters as L n(0), not n(0) (the start kick the MPCs' position gain would make of it).
    """
    start, n0 = (0.3, -0.2, 3.1), np.array([2e-3, -3e-3, 1e-3])
    states, _ = _track(200, start, (0.0, 0.0, 0.0), (0.4, -0.3, 0.5))
    states[:, 0::2] += np.random.default_rng(8).normal(0.0, 1e-3, (200, 3))
    states[0, 0::2] = np.array(start) + n0
    started = OdometryFilter(TS, 0.5, twist)
    started.start_at(*start)
    warm = OdometryFilter(TS, 0.5, twist)
    _run(warm, np.tile([start[0], 0.0, start[1], 0.0, start[2], 0.0], (50, 1)))
    est = _run(started, states)
    np.testing.assert_allclose(est, _run(warm, states), rtol=0, atol=1e-15)
    np.testing.assert_allclose(est[0], np.array(start) + started.gain * n0, rtol=0, atol=1e-15)
    started.reset()  # forgets the start: the first measurement initialises again
    np.testing.assert_array_equal(_run(started, states[:1])[0], states[0, 0::2])


def test_non_finite_start_is_refused_without_touching_the_state():
    filt = OdometryFilter(TS, 0.5)
    with pytest.raises(EstimatorError, match="start pose must be finite"):
        filt.start_at(0.0, math.nan, 0.0)
    assert not filt.initialized
