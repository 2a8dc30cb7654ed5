"""Inverse DC drive against step-by-step integrations of the armature circuit and of the coupled plant."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from robotino_geom_mpc.model import dynamics as model
from robotino_geom_mpc.control.inverse_drive import DriveError, InverseDrive, ZOHDrive
from robotino_geom_mpc.model.kinematics import MotorKinematics
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit

Ts = 0.01


@pytest.fixture(scope="module")
def robot():
    return load_params()[0]


def _zoh(robot, period_s=Ts):
    return ZOHDrive(robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a, period_s)


def _circuit(robot, i0, U, omega, omega_rate, period_s=Ts):
    """Integrate L i' = U - R i - Km (omega + omega' t) over one period: (mean, end) current."""
    R, L, Km = robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a

    def rhs(t, s):
        di = (U - R * s[0] - Km * (omega + omega_rate * t)) / L
        return [di, s[0]]

    sol = solve_ivp(rhs, (0.0, period_s), [i0, 0.0], method="DOP853", rtol=1e-12, atol=1e-14)
    return sol.y[1, -1] / period_s, sol.y[0, -1]


def test_zoh_relations_match_integration(robot):
    zoh = _zoh(robot)
    rng = np.random.default_rng(0)
    for _ in range(4):
        i0, U, omega, rate = rng.normal(0.3), rng.normal(0, 10), rng.normal(0, 100), rng.normal(0, 500)
        mean, end = _circuit(robot, i0, U, omega, rate)
        assert zoh.mean_current(i0, U, omega, rate) == pytest.approx(mean, abs=1e-11)
        assert zoh.end_current(i0, U, omega, rate) == pytest.approx(end, abs=1e-11)


@pytest.mark.parametrize("period_s", [0.001, 0.01, 0.05])
def test_commanded_current_is_the_period_average(robot, period_s):
    zoh = _zoh(robot, period_s)
    rng = np.random.default_rng(1)
    for _ in range(3):
        i_cmd, i0, omega, rate = rng.normal(0, 0.5), rng.normal(0, 0.5), rng.normal(0, 100), rng.normal(0, 500)
        U = zoh.voltage(i_cmd, i0, omega, rate)
        mean, _ = _circuit(robot, i0, U, omega, rate, period_s)
        assert mean == pytest.approx(i_cmd, abs=1e-10)


def test_effective_inductance_limits(robot):
    """L_d -> L when Ts >> L/R and -> 2 L (linear ramp whose mean is the target) when Ts << L/R."""
    L = robot.inductance_h
    assert _zoh(robot, 100 * robot.tau_electrical_s).effective_inductance_h == pytest.approx(L, rel=0.011)
    assert _zoh(robot, 1e-4 * robot.tau_electrical_s).effective_inductance_h == pytest.approx(2 * L, rel=1e-4)


def test_motor_kinematics_equal_the_model(robot):
    kin = MotorKinematics(robot)
    rng = np.random.default_rng(2)
    for theta in (0.0, 0.7, -2.9, 0.5 * np.pi):
        v, a = rng.normal(size=3), rng.normal(size=3)
        omega, rate = map(np.array, kin.speeds_and_rates(theta, v, a))
        np.testing.assert_allclose(omega, model.motor_speeds(theta, v, robot), atol=1e-12)
        np.testing.assert_allclose(kin.matrix(theta) @ v, omega, atol=1e-12)
        # d/dt omega along theta(t) = theta + v_theta t, v(t) = v + a t, central difference
        h = 1e-6
        plus = model.motor_speeds(theta + v[2] * h, v + a * h, robot)
        minus = model.motor_speeds(theta - v[2] * h, v - a * h, robot)
        np.testing.assert_allclose(rate, (plus - minus) / (2 * h), rtol=1e-6, atol=1e-6)


def _plant_period(robot, state, U):
    """One period of the coupled plant (model.coupled_rhs) with U held: end state and mean currents."""

    def rhs(t, s):
        return np.concatenate((model.coupled_rhs(s[:9], U, robot), s[6:9]))

    sol = solve_ivp(rhs, (0.0, Ts), np.concatenate((state, np.zeros(3))), method="DOP853", rtol=1e-10, atol=1e-12)
    return sol.y[:9, -1], sol.y[9:, -1] / Ts


def _run_drive(robot, commands, state, textbook=False):
    """Drive the coupled plant with the inverse drive; textbook=True uses U = R i + L (i_k - i_{k-1})/Ts + Km omega."""
    drive, kin = InverseDrive(robot, Ts), MotorKinematics(robot)
    means, previous = [], np.zeros(3)
    for i_cmd in commands:
        X = state[:6]
        acc = model.A_matrix(robot) @ X + model.g_theta(X[4], robot) @ model.wheel_forces(i_cmd, robot)
        omega, rate = map(np.array, kin.speeds_and_rates(X[4], X[1::2], acc[1::2]))
        if textbook:
            U = robot.resistance_ohm * i_cmd + robot.inductance_h * (i_cmd - previous) / Ts
            U = U + robot.torque_constant_n_m_per_a * omega
            previous = i_cmd
        else:
            U, saturated, _ = drive.step(i_cmd, omega, rate)
            assert not saturated
        state, mean = _plant_period(robot, state, U)
        means.append(mean)
    return np.array(means)


def test_commanded_currents_reached_on_the_coupled_plant(robot):
    """A step to constant currents on the moving robot: each period's mean current is the command."""
    state = np.array([0.0, 0.2, 0.0, -0.1, 0.3, 0.5, 0.0, 0.0, 0.0])
    commands = np.tile([0.4, -0.25, 0.1], (5, 1))
    means = _run_drive(robot, commands, state)
    np.testing.assert_allclose(means, commands, atol=2e-3)


def test_current_ramp_is_tracked_on_the_coupled_plant(robot):
    state = np.zeros(9)
    k = np.arange(1, 21)[:, None]
    commands = k * np.array([0.02, -0.015, 0.005])  # A per period
    error = np.abs(_run_drive(robot, commands, state) - commands).max()
    assert error < 1e-4
    # the textbook discretisation of L di/dt (backward difference, back-EMF at the tick) lags more
    textbook = np.abs(_run_drive(robot, commands, state, textbook=True) - commands).max()
    assert textbook > 10 * error


def test_saturation_is_reported_and_the_mean_current_predicted(robot):
    drive = InverseDrive(robot, Ts)
    omega, rate = np.array([50.0, -20.0, 0.0]), np.zeros(3)
    U, saturated, mean = drive.step(np.array([10.0, -10.0, 0.1]), omega, rate)
    assert saturated
    assert np.all(np.abs(U) <= robot.supply_voltage_v)
    assert U[0] == robot.supply_voltage_v and U[1] == -robot.supply_voltage_v
    for w in range(3):
        assert mean[w] == pytest.approx(_circuit(robot, 0.0, U[w], omega[w], 0.0)[0], abs=1e-10)


def test_float_path_equals_the_numpy_path(robot):
    """`InverseDrive.step`'s float path is `ZOHDrive`'s relations on arrays, and i = F r / (gear Km), to 1e-12."""
    drive, zoh = InverseDrive(robot, Ts), _zoh(robot)
    rng = np.random.default_rng(5)
    i_start = np.zeros(3)
    for _ in range(10):
        i_cmd, omega, rate = rng.normal(0, 0.3, 3), rng.normal(0, 50, 3), rng.normal(0, 200, 3)
        U, saturated, mean = drive.step(i_cmd.tolist(), omega.tolist(), rate.tolist())
        assert not saturated
        U_ref = zoh.voltage(i_cmd, i_start, omega, rate)
        np.testing.assert_allclose(U, U_ref, rtol=0.0, atol=1e-12 * np.abs(U_ref).max())
        np.testing.assert_allclose(mean, i_cmd, rtol=0.0, atol=0.0)
        i_start = zoh.end_current(i_start, U_ref, omega, rate)
        np.testing.assert_allclose(drive.current_estimate, i_start, rtol=0.0, atol=1e-12)
    forces = rng.normal(0, 20, 3)
    expected = model.currents_from_forces(forces, robot)
    np.testing.assert_allclose(drive.currents(forces.tolist()), expected, rtol=1e-15)


@pytest.mark.parametrize("elapsed_s", [1e-9, 0.003, Ts, 0.021])
def test_end_current_after_any_interval_matches_integration(robot, elapsed_s):
    """The `end` relation over an interval other than the period (a late, lost or repeated tick)."""
    zoh = _zoh(robot)
    rng = np.random.default_rng(2)
    for _ in range(3):
        i0, U, omega, rate = rng.normal(0.3), rng.normal(0, 10), rng.normal(0, 100), rng.normal(0, 500)
        _, end = _circuit(robot, i0, U, omega, rate, elapsed_s)
        assert zoh.end_current(i0, U, omega, rate, elapsed_s) == pytest.approx(end, abs=1e-11)


@pytest.mark.parametrize("saturate", [False, True])
def test_advance_predicts_the_start_current_after_the_elapsed_time(robot, saturate):
    """After `advance(t)` the estimate is the current after t of the last voltages, integrated (lost tick: 2 Ts)."""
    drive = InverseDrive(robot, Ts)
    omega, rate = [40.0, -30.0, 5.0], [100.0, -50.0, 0.0]
    drive.step([0.2, -0.1, 0.05], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    i0 = drive.current_estimate
    U, saturated, _ = drive.step([8.0 if saturate else 0.3, -0.2, 0.1], omega, rate)
    assert saturated == saturate
    one_period = drive.current_estimate
    drive.advance(2 * Ts)
    expected = [_circuit(robot, i0[w], U[w], omega[w], rate[w], 2 * Ts)[1] for w in range(3)]
    np.testing.assert_allclose(drive.current_estimate, expected, atol=1e-10)
    drive.advance(Ts)  # one period: the prediction of the step itself
    np.testing.assert_allclose(drive.current_estimate, one_period, atol=1e-12)
    assert all(type(v) is float for v in drive.current_estimate)  # the per-tick path's floats


def test_bad_input_raises(robot):
    with pytest.raises(DriveError, match="period_s"):
        InverseDrive(robot, 0.0)
    with pytest.raises(DriveError, match="elapsed_s"):
        InverseDrive(robot, Ts).advance(0.0)
    with pytest.raises(DriveError, match="elapsed_s"):
        _zoh(robot).end_current(0.0, 1.0, 0.0, 0.0, float("nan"))
    with pytest.raises(DriveError, match="currents"):
        InverseDrive(robot, Ts).reset(np.array([1.0, np.nan, 0.0]))
    with pytest.raises(DriveError, match="inductance_h"):
        ZOHDrive(1.0, -1.0, 0.05, Ts)
