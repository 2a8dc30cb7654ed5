"""One control step against the model: decoupling field, drive simulated on the coupled plant, input errors."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from robotino_geom_mpc.model import dynamics as model
from robotino_geom_mpc.control.motion_controller import ControllerInputError, MotionController, states_from_odometry
from robotino_geom_mpc.geometric.decoupling import DecouplingField
from robotino_geom_mpc.control.mpc import DecoupledMPC, axis_dampings
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.model.plant import RobotinoPlant

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def params():
    return load_params()


X0 = np.array([0.01, 0.15, -0.02, -0.1, 0.4, 0.3])


def _preview(X, control, offset=(0.0, 0.0, 0.0)):
    steps = np.arange(1, control.horizon + 1)[:, None] * control.period_s
    return X[0::2] + steps * X[1::2] + np.asarray(offset)


def _noisy_track(X, control, n, seed=0, sigma=1e-3):
    """n states along the constant-velocity track of X, with white noise on the pose (x, y, theta)."""
    t = np.arange(n)[:, None] * control.period_s
    states = np.tile(X, (n, 1))
    states[:, 0::2] = X[0::2] + t * X[1::2] + np.random.default_rng(seed).normal(0.0, sigma, (n, 3))
    return states


def _period_on_plant(robot, state, U, Ts):
    """Coupled plant (model.coupled_rhs) over one period with U held: end state and mean currents."""

    def rhs(t, s):
        return np.concatenate((model.coupled_rhs(s[:9], U, robot), s[6:9]))

    sol = solve_ivp(rhs, (0.0, Ts), np.concatenate((state, np.zeros(3))), method="DOP853", rtol=1e-10, atol=1e-12)
    return sol.y[:9, -1], sol.y[9:, -1] / Ts


def test_step_is_mpc_then_decoupling_field_then_currents(params):
    robot, control = params
    ctl = MotionController(robot, control)
    Y_d = _preview(X0, control, (1e-4, -2e-4, 1e-4))
    out = ctl.step(X0, Y_d)
    expected_u = MotionController(robot, control).u_prev + DecoupledMPC(robot, control).solve(
        X0.reshape(3, 2), np.zeros(3), Y_d
    )[0]
    np.testing.assert_allclose(out.u, expected_u, rtol=1e-12, atol=1e-12)
    theta_mid = X0[4] + 0.5 * control.period_s * X0[5]
    F = DecouplingField(robot).field(theta_mid) @ out.u
    np.testing.assert_allclose(out.currents, model.currents_from_forces(F, robot), rtol=1e-12, atol=1e-15)
    assert not out.saturated and not out.infeasible and out.compute_time_s > 0
    # the voltages are the drive's relation (eq. 10) for these currents, from rest
    v = X0[1::2]
    omega, rate = map(np.array, ctl.kinematics.speeds_and_rates(X0[4], v, out.u - axis_dampings(robot) * v))
    U = ctl.drive.zoh.voltage(np.array(out.currents), np.zeros(3), omega, rate)
    np.testing.assert_allclose(out.voltages, U, rtol=1e-12, atol=1e-12)


def test_one_period_interval_is_the_default(params):
    """dt_s = Ts is what None means: the same voltages along a noisy track, filter on."""
    robot, control = params
    ctl, twin = MotionController(robot, control), MotionController(robot, control)
    for X in _noisy_track(X0, control, 20):
        Y_d = _preview(X, control, (1e-4, 0, 0))
        np.testing.assert_array_equal(ctl.step(X, Y_d).voltages, twin.step(X, Y_d, control.period_s).voltages)


def test_voltages_give_the_commanded_currents_on_the_coupled_plant(params):
    """Several periods on the moving robot: each period's mean current is the command (drive lag aside)."""
    robot, control = params
    ctl = MotionController(robot, control)
    state = np.concatenate((X0, np.zeros(3)))
    for k in range(4):
        out = ctl.step(state[:6], _preview(state[:6], control, (2e-5 * (k + 1), 1e-5, -1e-5)))
        state, mean = _period_on_plant(robot, state, out.voltages, control.period_s)
        np.testing.assert_allclose(mean, out.currents, atol=2e-3 * max(1.0, np.abs(out.currents).max()))


def test_saturation_clips_and_feeds_back_the_achieved_acceleration(params):
    robot, control = params
    ctl = MotionController(robot, replace(control, current_limit_a=0.0))  # the paper's per-wheel clip
    out = ctl.step(X0, _preview(X0, control, (0.2, 0.0, 0.0)))
    assert out.saturated
    assert np.max(np.abs(out.voltages)) == pytest.approx(robot.supply_voltage_v)
    _, mean = _period_on_plant(robot, np.concatenate((X0, np.zeros(3))), out.voltages, control.period_s)
    theta_mid = X0[4] + 0.5 * control.period_s * X0[5]
    achieved = model.acceleration_block(theta_mid, robot) @ model.wheel_forces(mean, robot)
    np.testing.assert_allclose(ctl.u_prev, achieved, atol=0.01 * np.abs(achieved).max())
    assert np.abs(out.u).max() > 2 * np.abs(achieved).max()


@pytest.mark.parametrize("tau", [0.0, 0.5])
def test_reset_restores_the_initial_behaviour(params, tau):
    robot, control = params
    ctl = MotionController(robot, replace(control, odometry_filter_time_constant_s=tau))
    states = _noisy_track(X0, control, 5)
    first = [ctl.step(X, _preview(X, control, (1e-4, 0, 0))).voltages for X in states]
    ctl.step(X0, _preview(X0, control, (3e-4, 0, 0)))
    ctl.reset()
    again = [ctl.step(X, _preview(X, control, (1e-4, 0, 0))).voltages for X in states]
    np.testing.assert_array_equal(first, again)


@pytest.mark.parametrize(
    "X, preview, dt_s, match",
    [
        (np.array([0, 0, np.nan, 0, 0, 0.0]), np.zeros((4, 3)), None, "X must be finite"),
        (np.zeros(6), np.full((4, 3), np.inf), None, "preview must be finite"),
        (np.zeros(5), np.zeros((4, 3)), None, r"X must have shape \(6,\)"),
        (np.zeros(6), np.zeros((3, 3)), None, r"preview must have shape \(4, 3\)"),
        (X0, np.zeros((4, 3)), 0.0, "dt_s must be"),
        (X0, np.zeros((4, 3)), -0.01, "dt_s must be"),
        (X0, np.zeros((4, 3)), np.nan, "dt_s must be"),
        (X0, np.zeros((4, 3)), np.inf, "dt_s must be"),
        (X0, np.zeros((4, 3)), True, "dt_s must be"),
        (X0, np.zeros((4, 3)), "0.01", "dt_s must be"),
    ],
)
def test_bad_input_raises_and_leaves_the_state(params, X, preview, dt_s, match):
    robot, control = params
    control = replace(control, odometry_filter_time_constant_s=0.5)
    ctl, twin = MotionController(robot, control), MotionController(robot, control)
    states = _noisy_track(X0, control, 3)
    for ctrl in (ctl, twin):
        for X_k in states[:2]:
            ctrl.step(X_k, _preview(X_k, control, (1e-4, 0, 0)))
    u_before, i_before = ctl.u_prev.copy(), ctl.drive.current_estimate.copy()
    estimate_before = ctl.estimator.estimate
    with pytest.raises(ControllerInputError, match=match):
        ctl.step(X, preview, dt_s)
    np.testing.assert_array_equal(ctl.u_prev, u_before)
    np.testing.assert_array_equal(ctl.drive.current_estimate, i_before)
    assert ctl.estimator.estimate == estimate_before
    Y_d = _preview(states[2], control, (1e-4, 0, 0))
    assert ctl.step(states[2], Y_d)[:3] == twin.step(states[2], Y_d)[:3]


@pytest.mark.parametrize("tau", [0.0, 0.5])
def test_constrained_mode_equals_closed_form_when_limits_are_inactive(params, tau):
    robot, control = params
    control = replace(control, odometry_filter_time_constant_s=tau)
    a = MotionController(robot, control)
    b = MotionController(robot, replace(control, mode="constrained"))
    for k, X in enumerate(_noisy_track(X0, control, 3, sigma=1e-5)):  # states along X0's velocity
        Y_d = _preview(X, control, (1e-5 * k, 0, 0))
        out_a, out_b = a.step(X, Y_d), b.step(X, Y_d)
        np.testing.assert_allclose(out_b.voltages, out_a.voltages, atol=1e-9)
        assert not out_b.infeasible


def test_states_from_odometry_inverts_the_plants_measurement(params):
    robot, _ = params
    plant = RobotinoPlant(robot, state0=np.concatenate((X0, np.zeros(3))))
    np.testing.assert_allclose(states_from_odometry(*plant.odometry()), X0, atol=1e-15)
    with pytest.raises(ControllerInputError, match="twist_body"):
        states_from_odometry(np.zeros(3), np.zeros(2))


def test_filter_off_is_the_raw_pose_and_on_is_the_same_law_on_the_estimate(params):
    """Filter on = the unfiltered computation (tau = 0) fed the estimated pose, bit for bit."""
    robot, control = params
    on = MotionController(robot, replace(control, odometry_filter_time_constant_s=0.5))
    off = MotionController(robot, replace(control, odometry_filter_time_constant_s=0.0))
    assert off.estimator is None
    states = _noisy_track(X0, control, 30, seed=4)
    for k, X in enumerate(states):
        Y_d = _preview(X0, control, (0.0, 0.0, 0.0)) + (k + 1e-3) * control.period_s * X0[1::2]
        out_on = on.step(X, Y_d)
        X_est = X.copy()
        X_est[0::2] = on.estimator.estimate
        out_off = off.step(X_est, Y_d)
        assert out_on[:5] == out_off[:5]
    assert np.abs(X_est[0::2] - X[0::2]).max() > 1e-4  # the estimate did differ from the measurement


def test_measured_heading_jumping_by_two_pi_does_not_disturb_the_filtered_controller(params):
    robot, control = params
    control = replace(control, odometry_filter_time_constant_s=0.5)
    a, b = MotionController(robot, control), MotionController(robot, control)
    states = _noisy_track(X0, control, 8, seed=5)
    for k, X in enumerate(states):
        Y_d = _preview(X, control, (1e-5, 0.0, 1e-5))
        X_wrapped = X.copy()
        X_wrapped[4] += 2 * np.pi if k >= 4 else 0.0
        out_a, out_b = a.step(X, Y_d), b.step(X_wrapped, Y_d)
        np.testing.assert_allclose(out_b.voltages, out_a.voltages, rtol=0, atol=1e-9)
    raw = MotionController(robot, replace(control, odometry_filter_time_constant_s=0.0, current_limit_a=0.0))
    assert raw.step(X_wrapped, Y_d).saturated  # the raw pose would have been an error of 2 pi


def test_filter_keeps_odometry_noise_out_of_the_currents_in_closed_loop(params):
    """Robustness scenario (model mismatch, 1 mm / 1 mrad pose noise): raw pose exceeds the nominal current."""
    robot, control = params
    peaks = {}
    for tau in (0.0, 0.5):
        filtered = replace(control, odometry_filter_time_constant_s=tau, current_limit_a=0.0)
        run = run_scenario(RunConfig("robustness", robot, filtered, duration_s=1.5))
        peaks[tau] = np.abs(run.currents).max()
        saturated = run.flags["saturated"].any()
        error = np.hypot(*(run.pose[:, :2] - run.reference[:, :2]).T)
    assert peaks[0.0] > robot.nominal_current_a
    assert peaks[0.5] <= robot.nominal_current_a and not saturated
    assert error.max() < 1e-3


def test_step_interval_is_one_period_unless_the_stamps_say_otherwise():
    from robotino_geom_mpc.control.motion_controller import step_interval

    period = 10_000_000
    assert step_interval(5 * period, None, period) is None  # the first measurement
    assert step_interval(5 * period, 4 * period, period) is None  # on time
    assert step_interval(5 * period, 3 * period, period) == pytest.approx(0.02)  # a lost tick
    assert step_interval(5 * period + 11_000_000, 4 * period, period) == pytest.approx(0.021)  # a late one
