"""The per-axis MPC (eqs. 48-56) against independent truths: ODE integration, step-by-step simulation, a QP solver."""

from dataclasses import replace

import numpy as np
import pytest
import quadprog
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from robotino_geom_mpc.control.mpc import (
    DecoupledMPC,
    MPCError,
    axis_dampings,
    discretize_axis,
    prediction_matrices,
)
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def params():
    return load_params()


@pytest.mark.parametrize("damping", [0.0, 0.2436, 3.0])
def test_discretisation_matches_fine_integration(damping):
    Ts = 0.01
    A_d, B_d = discretize_axis(damping, Ts)
    rng = np.random.default_rng(1)
    for _ in range(3):
        x0, u = rng.normal(size=2), rng.normal()
        sol = solve_ivp(
            lambda t, x: [x[1], -damping * x[1] + u], (0.0, Ts), x0, method="DOP853", rtol=1e-12, atol=1e-14
        )
        np.testing.assert_allclose(A_d @ x0 + B_d * u, sol.y[:, -1], rtol=0, atol=1e-12)


def test_discretisation_without_friction_is_the_double_integrator():
    Ts = 0.02
    A_d, B_d = discretize_axis(0.0, Ts)
    np.testing.assert_allclose(A_d, [[1.0, Ts], [0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(B_d, [Ts**2 / 2, Ts], atol=1e-15)


@pytest.mark.parametrize("period_s", [0.001, 0.01, 0.1])
@pytest.mark.parametrize("damping_ts", [0.0, 1e-12, 1e-7, 1e-3, 0.05, 0.0999999, 0.1, 0.3, 2.0, 40.0])
def test_closed_form_discretisation_equals_van_loan_expm(damping_ts, period_s):
    """The closed form against expm of [[A, B], [0, 0]] Ts (Van Loan), on both sides of the series switch."""
    damping = damping_ts / period_s
    A_d, B_d = discretize_axis(damping, period_s)
    M = np.array([[0.0, 1.0, 0.0], [0.0, -damping, 1.0], [0.0, 0.0, 0.0]])
    E = expm(M * period_s)
    np.testing.assert_allclose(A_d, E[:2, :2], rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(B_d, E[:2, 2], rtol=1e-12, atol=0.0)


def _simulate(A_d, B_d, x, u_prev, delta_U):
    """Outputs y(k+1)..y(k+N) of eq. (49) stepped one period at a time."""
    ys, u = [], u_prev
    for du in delta_U:
        u = u + du
        x = A_d @ x + B_d * u
        ys.append(x[0])
    return np.array(ys)


@pytest.mark.parametrize("horizon", [1, 2, 4, 7])
def test_predictions_equal_step_by_step_simulation(horizon):
    rng = np.random.default_rng(horizon)
    A_d, B_d = discretize_axis(0.3, 0.01)
    G_p, F_1p, F_2p = prediction_matrices(A_d, B_d, horizon)
    for _ in range(5):
        x, u_prev, dU = rng.normal(size=2), rng.normal(), rng.normal(size=horizon)
        np.testing.assert_allclose(G_p @ x + F_1p @ dU + F_2p * u_prev, _simulate(A_d, B_d, x, u_prev, dU), atol=1e-14)


def test_printed_sums_of_eq_53_do_not_predict():
    """Erratum 3: the printed third row H sum_{i=1}^{2} (A^i + I) B is not the model's prediction."""
    A_d, B_d = discretize_axis(0.3, 0.01)
    _, _, F_2p = prediction_matrices(A_d, B_d, 4)
    printed = sum((np.linalg.matrix_power(A_d, i) + np.eye(2)) @ B_d for i in (1, 2))[0]
    truth = _simulate(A_d, B_d, np.zeros(2), 1.0, np.zeros(4))[2]
    assert F_2p[2] == pytest.approx(truth, rel=1e-12)
    assert abs(printed - truth) > 0.1 * abs(truth)


def test_stacked_prediction_equals_simulation_per_axis(params):
    robot, control = params
    mpc = DecoupledMPC(robot, control)
    rng = np.random.default_rng(7)
    x, u_prev, dU = rng.normal(size=(3, 2)), rng.normal(size=3), rng.normal(size=(control.horizon, 3))
    Y = mpc.predict(x, u_prev, dU)
    for a, damping in enumerate(axis_dampings(robot)):
        A_d, B_d = discretize_axis(damping, control.period_s)
        np.testing.assert_allclose(Y[:, a], _simulate(A_d, B_d, x[a], u_prev[a], dU[:, a]), atol=1e-14)


def _qp_by_simulation(A_d, B_d, x, u_prev, Y_d, q, r):
    """Minimise 1/2 q |Y_d - Y|^2 + 1/2 r |dU|^2 with Y built column by column from the simulation."""
    N = len(Y_d)
    free = _simulate(A_d, B_d, x, u_prev, np.zeros(N))
    M = np.column_stack([_simulate(A_d, B_d, np.zeros(2), 0.0, np.eye(N)[l]) for l in range(N)])
    H = q * M.T @ M + r * np.eye(N)
    g = q * M.T @ (Y_d - free)  # quadprog minimises 1/2 z'Hz - g'z
    return quadprog.solve_qp(H, g)[0]


@pytest.mark.parametrize("seed", range(4))
def test_closed_form_equals_qp_solver(params, seed):
    robot, control = params
    mpc = DecoupledMPC(robot, control)
    rng = np.random.default_rng(seed)
    N = control.horizon
    x = rng.normal(scale=[1e-3, 1e-2], size=(3, 2))
    u_prev = rng.normal(scale=0.1, size=3)
    Y_d = rng.normal(scale=1e-3, size=(N, 3))
    dU = mpc.solve(x, u_prev, Y_d)
    first = mpc.delta_u(x.ravel(), u_prev, Y_d)
    for a in range(3):
        ref = _qp_by_simulation(mpc.A_d[a], mpc.B_d[a], x[a], u_prev[a], Y_d[:, a], mpc.q[a], mpc.r[a])
        np.testing.assert_allclose(dU[:, a], ref, rtol=0, atol=1e-9)
        assert first[a] == pytest.approx(ref[0], abs=1e-9)


def test_gain_solves_the_normal_equations_of_eq_55(params):
    """dJ/d(dU) = 0 at the closed form for arbitrary weights (eq. 55)."""
    robot, control = params
    control = replace(control, q_x=3.0, q_y=50.0, q_theta=7.0, r_x=0.2, r_y=1e-4, r_theta=1.0, horizon=6)
    mpc = DecoupledMPC(robot, control)
    rng = np.random.default_rng(3)
    x, u_prev, Y_d = rng.normal(size=(3, 2)), rng.normal(size=3), rng.normal(size=(6, 3))
    dU = mpc.solve(x, u_prev, Y_d)
    Y = mpc.predict(x, u_prev, dU)
    for a in range(3):
        grad = -mpc.q[a] * mpc.F_1p[a].T @ (Y_d[:, a] - Y[:, a]) + mpc.r[a] * dU[:, a]
        assert np.max(np.abs(grad)) < 1e-10 * (1 + np.max(np.abs(mpc.q[a] * mpc.F_1p[a].T @ Y_d[:, a])))


def test_bad_settings_raise():
    with pytest.raises(MPCError, match="damping"):
        discretize_axis(float("nan"), 0.01)
    with pytest.raises(MPCError, match="period_s"):
        discretize_axis(0.1, 0.0)
    A_d, B_d = discretize_axis(0.1, 0.01)
    with pytest.raises(MPCError, match="horizon"):
        prediction_matrices(A_d, B_d, 0)
    with pytest.raises(MPCError, match="B_d"):
        prediction_matrices(A_d, np.ones(3), 4)


def test_delta_u_is_the_first_increment_of_eq_56(params):
    """`delta_u` (Python floats, the controller's per-tick path) is the first row of eq. (56)'s whole sequence
    (`solve`), to 1e-12.
    """
    robot, control = params
    mpc = DecoupledMPC(robot, control)
    rng = np.random.default_rng(7)
    for _ in range(20):
        X, u_prev = rng.normal(0.0, 1.0, 6), rng.normal(0.0, 2.0, 3)
        Y_d = rng.normal(0.0, 1.0, (control.horizon, 3))
        fast = mpc.delta_u(X.tolist(), u_prev.tolist(), Y_d.tolist())
        assert type(fast) is list and all(type(v) is float for v in fast)
        reference = mpc.solve(X.reshape(3, 2), u_prev, Y_d)[0]
        np.testing.assert_allclose(fast, reference, rtol=0.0, atol=1e-12 * max(1.0, np.abs(reference).max()))
