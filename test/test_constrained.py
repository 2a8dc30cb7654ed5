"""Constrained mode: QP against the closed form, limits checked with the model, optimality against quadprog."""

import sys
from dataclasses import replace

import numpy as np
import pytest
import quadprog
from scipy.integrate import solve_ivp

from robotino_geom_mpc.model import dynamics as model
from robotino_geom_mpc.control.constrained import ConstrainedMPC, ConstrainedModeError
from robotino_geom_mpc.control.motion_controller import MotionController
from robotino_geom_mpc.geometric.decoupling import DecouplingField
from robotino_geom_mpc.control.inverse_drive import ZOHDrive
from robotino_geom_mpc.model.kinematics import MotorKinematics
from robotino_geom_mpc.control.mpc import DecoupledMPC, axis_dampings
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.scenarios import get_scenario

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def setup():
    robot, control = load_params()
    control = replace(control, mode="constrained")
    mpc = DecoupledMPC(robot, control)
    return robot, control, mpc, ConstrainedMPC(robot, control, mpc)


def _moving_state():
    return np.array([0.01, 0.2, -0.02, 0.1, 0.3, 0.2])


def _currents(robot, theta_mid, u):
    """Wheel currents of u with the decoupling field and the model (independent of the QP's rows)."""
    F = DecouplingField(robot).field(theta_mid) @ u
    return model.currents_from_forces(F, robot)


def test_qp_equals_closed_form_when_limits_are_inactive(setup):
    robot, control, mpc, qp = setup
    X = _moving_state()
    u_prev = np.array([0.1, -0.05, 0.2])
    Y_d = X[0::2] + np.outer(np.arange(1, 5) * control.period_s, X[1::2])
    closed = mpc.solve(X.reshape(3, 2), u_prev, Y_d)
    dU, infeasible = qp.solve_increments(X, u_prev, Y_d, np.zeros(3), use_closed_form=False)
    assert not infeasible
    np.testing.assert_allclose(dU, closed, rtol=0, atol=1e-9)
    # and the limits are indeed inactive there
    h, G = qp.constraint_rows(X, u_prev, Y_d, np.zeros(3))
    assert np.max(np.abs(h + G @ closed.ravel())) < 0.9


def test_active_limits_hold_and_the_optimum_matches_quadprog(setup):
    robot, control, mpc, qp = setup
    X = _moving_state()
    u_prev = np.zeros(3)
    Y_d = np.tile(X[0::2] + np.array([0.05, -0.03, 0.2]), (control.horizon, 1))  # far: amperes wanted
    closed = mpc.solve(X.reshape(3, 2), u_prev, Y_d)
    theta_mid = X[4] + 0.5 * control.period_s * X[5]
    assert np.max(np.abs(_currents(robot, theta_mid, u_prev + closed[0]))) > 2 * robot.nominal_current_a
    dU, infeasible = qp.solve_increments(X, u_prev, Y_d, np.zeros(3))
    assert not infeasible
    u = u_prev + np.cumsum(dU, axis=0)
    # currents of the applied step from the model, and of the later steps at the reference's headings
    assert np.max(np.abs(_currents(robot, theta_mid, u[0]))) <= robot.nominal_current_a * (1 + 1e-6)
    for j in range(1, control.horizon):
        heading = 0.5 * (Y_d[j - 1, 2] + Y_d[j, 2])
        assert np.max(np.abs(_currents(robot, heading, u[j]))) <= robot.nominal_current_a * (1 + 1e-6)
    # the applied step's voltage from the drive relations with the measured velocity
    zoh = ZOHDrive(robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a, control.period_s)
    v = X[1::2]
    omega, rate = map(np.array, MotorKinematics(robot).speeds_and_rates(X[4], v, u[0] - axis_dampings(robot) * v))
    U0 = zoh.voltage(_currents(robot, theta_mid, u[0]), np.zeros(3), omega, rate)
    assert np.max(np.abs(U0)) <= robot.supply_voltage_v * (1 + 1e-6)
    # on the coupled plant the current stays near the limit all along the period, not only on average
    # (average and end are bounded; the back-EMF rising within the period allows a hump of ~1 %)
    sol = solve_ivp(
        lambda t, s: model.coupled_rhs(s, U0, robot),
        (0.0, control.period_s),
        np.concatenate((X, np.zeros(3))),
        method="DOP853",
        rtol=1e-10,
        atol=1e-12,
        dense_output=True,
    )
    currents_along = sol.sol(np.linspace(0.0, control.period_s, 201))[6:9]
    assert np.max(np.abs(currents_along)) <= robot.nominal_current_a * 1.02
    # optimality: a second solver (dual active set) on the same QP
    P = np.zeros((12, 12))
    for a in range(3):
        P[a::3, a::3] = mpc.hessian[a]
    e = mpc.free_error(X.reshape(3, 2), u_prev, Y_d)
    g = np.zeros(12)
    for a in range(3):
        g[a::3] = mpc.q[a] * mpc.F_1p[a].T @ e[:, a]
    h, G = qp.constraint_rows(X, u_prev, Y_d, np.zeros(3))
    C = np.vstack((-G, G)).T  # quadprog: C^T z >= b
    b = np.concatenate((h - 1.0, -1.0 - h))
    ref = quadprog.solve_qp(P, g, C, b)[0]
    np.testing.assert_allclose(dU.ravel(), ref, rtol=0, atol=1e-6 * np.max(np.abs(ref)))


def _min_total_violation(G, h, eps=1e-7):
    """min sum(s), |G z + h| <= 1 + s, s >= 0, by quadprog with a tiny regulariser (an LP check)."""
    m, n = G.shape
    P = eps * np.eye(n + m)
    q = -np.concatenate((np.zeros(n), np.ones(m)))  # quadprog minimises 1/2 x'Px - q'x
    eye = np.eye(m)
    C = np.vstack((np.hstack((-G, eye)), np.hstack((G, eye)), np.hstack((np.zeros((m, n)), eye)))).T
    b = np.concatenate((h - 1.0, -1.0 - h, np.zeros(m)))
    x = quadprog.solve_qp(P, q, C, b)[0]
    return np.sum(np.maximum(np.abs(G @ x[:n] + h) - 1.0, 0.0))


def test_infeasible_state_is_flagged_with_least_violation(setup):
    robot, control, mpc, qp = setup
    # 2.5 m/s along x: even -i_nom cannot bring two wheels' voltages below the supply
    X = np.array([0.0, 2.5, 0.0, 0.0, 0.0, 0.0])
    Y_d = X[0::2] + np.outer(np.arange(1, 5) * control.period_s, X[1::2])
    dU, infeasible = qp.solve_increments(X, np.zeros(3), Y_d, np.zeros(3))
    assert infeasible
    assert np.all(np.isfinite(dU))
    h, G = qp.constraint_rows(X, np.zeros(3), Y_d, np.zeros(3))
    violation = np.sum(np.maximum(np.abs(G @ dU.ravel() + h) - 1.0, 0.0))
    best = _min_total_violation(G, h)
    assert best > 1e-3
    assert violation <= best + 1e-5


def test_controller_in_constrained_mode_reports_infeasible_and_stays_in_supply(setup):
    robot, control, _, _ = setup
    ctl = MotionController(robot, control)
    X = np.array([0.0, 2.5, 0.0, 0.0, 0.0, 0.0])
    out = ctl.step(X, X[0::2] + np.outer(np.arange(1, 5) * control.period_s, X[1::2]))
    assert out.infeasible
    assert np.all(np.isfinite(out.voltages)) and np.max(np.abs(out.voltages)) <= robot.supply_voltage_v
    # a feasible state afterwards clears the flag
    out = ctl.step(np.zeros(6), np.zeros((4, 3)))
    assert not out.infeasible


# --- the fast formulation against the direct one, and against OSQP on the benchmark's inputs ---


def _reference_rows(robot, control, mpc, X, u_prev, Y_d, i_start):
    """The constraint rows built period by period (the former implementation): h (9N,), G (9N, 3N)."""
    N, Ts = control.horizon, control.period_s
    zoh = ZOHDrive(robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a, Ts)
    field, amperes_per_newton = DecouplingField(robot), robot.r / (robot.gear_ratio * robot.torque_constant_n_m_per_a)
    kin, damping = MotorKinematics(robot), axis_dampings(robot)
    theta, w = X[4], X[5]
    u, v, i0 = np.zeros((3, 1 + 3 * N)), np.zeros((3, 1 + 3 * N)), np.zeros((3, 1 + 3 * N))
    u[:, 0], v[:, 0], i0[:, 0] = u_prev, X[1::2], i_start
    rows = []
    for j in range(N):
        u[np.arange(3), 1 + 3 * j + np.arange(3)] += 1.0
        heading, mid = (theta, theta + 0.5 * Ts * w) if j == 0 else (Y_d[j - 1, 2], 0.5 * (Y_d[j - 1, 2] + Y_d[j, 2]))
        # omega = W(theta) v with W(theta) = W(0) diag(R(theta)^T, 1): omega' = W (a + theta' (v_y, -v_x, 0))
        rate = u - damping[:, None] * v
        rate[0] += w * v[1]
        rate[1] -= w * v[0]
        W = kin.matrix(heading)
        current = amperes_per_newton * field.field(mid) @ u
        voltage = zoh.voltage(current, i0, W @ v, W @ rate)
        end = zoh.end_current(i0, voltage, W @ v, W @ rate)
        rows += [current / robot.nominal_current_a, end / robot.nominal_current_a, voltage / robot.supply_voltage_v]
        i0 = end
        v = mpc.A_d[:, 1, 1][:, None] * v + mpc.B_d[:, 1][:, None] * u
    rows = np.concatenate(rows)
    return rows[:, 0], rows[:, 1:]


def test_rows_equal_the_period_by_period_construction(setup):
    robot, control, mpc, qp = setup
    rng = np.random.default_rng(3)
    for _ in range(50):
        X = rng.normal(0.0, [0.5, 0.5, 0.5, 0.5, 3.0, 2.0])
        u_prev, i_start = rng.normal(0.0, 1.0, 3), rng.normal(0.0, 0.5, 3)
        Y_d = X[0::2] + rng.normal(0.0, 0.1, (control.horizon, 3))
        h_ref, G_ref = _reference_rows(robot, control, mpc, X, u_prev, Y_d, i_start)
        h, G = qp.constraint_rows(X, u_prev, Y_d, i_start)
        np.testing.assert_allclose(h, h_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(G, G_ref, rtol=0, atol=1e-12)
        z = mpc.solve(X.reshape(3, 2), u_prev, Y_d).ravel()
        # the per-tick check (one product, cos, two multiplies, one product on fixed buffers) to 1e-12
        np.testing.assert_allclose(qp.closed_form_rows(X, u_prev, Y_d, i_start), h_ref + G_ref @ z, rtol=0, atol=1e-12)
        # and the QP's data: no linear cost at the closed form (its gradient P z* + f vanishes there)
        P, f, h, G = qp.qp_problem(X, u_prev, Y_d, i_start)
        np.testing.assert_allclose(P @ z + f, 0.0, rtol=0, atol=1e-13 * max(1.0, np.abs(f).max()))  # |f| ~ 1e2


@pytest.fixture(scope="module")
def bench_calls():
    from robotino_geom_mpc.bench.constrained import constrained_inputs, qp_calls

    _, control = load_params()
    return {name: qp_calls(inputs, control) for name, inputs in constrained_inputs(400, 60).items()}


def test_solve_equals_osqp_on_the_same_qp_and_the_closed_form_where_no_limit_binds(setup, bench_calls):
    """Every tick of paper-circle, robustness and the binding transients: u to 1e-6 of OSQP (tight)."""
    from robotino_geom_mpc.bench.constrained import OsqpConstrainedQP

    robot, control, mpc, _ = setup
    binding = {}
    for name, calls in bench_calls.items():
        model = get_scenario("robustness").controller_model(robot) if name == "robustness" else robot
        qp = ConstrainedMPC(model, control, DecoupledMPC(model, control))
        reference = OsqpConstrainedQP(qp)
        for call in calls:
            u_osqp = call.u_prev + reference.solve(*reference.problem(call))[:3]
            np.testing.assert_allclose(call.u, u_osqp, rtol=0, atol=1e-6 * max(1.0, np.abs(u_osqp).max()))
            if call.closed_form:  # bit for bit the closed-form mode's u
                du = qp.mpc.delta_u(call.X.tolist(), call.u_prev.tolist(), call.Y_d.tolist())
                assert call.u.tolist() == [a + b for a, b in zip(call.u_prev.tolist(), du)]
        # the float path (fresh solver, the same sequence: the same warm starts) bit for bit the array path
        qp.reset()
        for call in calls:
            u, _ = qp.solve_floats(call.X.tolist(), call.u_prev.tolist(), call.Y_d.tolist(), call.i_start.tolist())
            assert u == call.u.tolist()
        binding[name] = sum(not call.closed_form for call in calls)
    # the limits bind through the transients (the QP is exercised) and hardly on the nominal runs
    assert binding["circle-step"] >= 5 and binding["position-step"] >= 5
    assert binding["paper-circle"] == 0


def test_without_daqp_the_constrained_mode_says_what_to_install(monkeypatch):
    """daqp has no rosdep key: on a ROS install without it the constrained mode stops with the pip line."""
    robot, control = load_params()
    control = replace(control, mode="constrained")
    monkeypatch.setitem(sys.modules, "daqp", None)  # import daqp raises ImportError
    monkeypatch.delitem(sys.modules, "robotino_geom_mpc.control.warm_qp", raising=False)
    with pytest.raises(ConstrainedModeError, match=r"pip install 'daqp"):
        ConstrainedMPC(robot, control, DecoupledMPC(robot, control))
    with pytest.raises(ConstrainedModeError):
        MotionController(robot, control)
