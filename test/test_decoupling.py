"""Decoupling field T(theta) (eqs. 33-37) and conditions (12)-(21) on a theta grid including pi/2 + k pi."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from robotino_geom_mpc.geometric import decoupling as dec
from robotino_geom_mpc.geometric import subspaces as geo
from robotino_geom_mpc.model.dynamics import A_matrix, acceleration_block, g_theta
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import preset_file

pytestmark = pytest.mark.unit

PRESETS = ("robotino3", "robotino2")


@pytest.fixture(scope="module", params=PRESETS)
def robot(request):
    return load_params(preset_file(request.param))[0]


@pytest.fixture(scope="module")
def report(robot):
    return dec.check_decoupling(robot, n_theta=3600)


def test_grid_has_3600_points_and_the_claimed_singularities(report):
    grid = dec.theta_grid(3600)
    assert grid.size == report.theta_grid_points >= 3600
    assert report.singular_points_included
    for t in (-np.pi / 2, np.pi / 2, -np.pi, np.pi):
        assert np.any(grid == t)


def test_all_conditions_hold_with_small_residuals(report):
    assert report.max_residual <= 1e-9
    assert report.fast_vs_toolbox_rel <= 1e-12
    assert {c.equation for c in report.conditions} == {f"({k})" for k in range(12, 22)}
    assert all(c.passed for c in report.conditions), report.conditions
    assert report.passed


def test_fast_path_equals_the_inverse_of_the_acceleration_block_on_the_grid(robot):
    grid = dec.theta_grid(3600)
    T = dec.DecouplingField(robot).field(grid)
    # independent truth: the inverse of the model's 3x3 block, angle by angle
    G3 = np.stack([acceleration_block(t, robot) for t in grid])
    assert np.max(np.abs(T - np.linalg.inv(G3))) <= 1e-12 * np.max(np.abs(T))
    g = np.stack([g_theta(t, robot) for t in grid])
    assert np.max(np.abs(g @ T - dec.B_decoupled())) <= 1e-9


def test_toolbox_route_equals_fast_path(robot):
    grid = np.union1d(np.linspace(-np.pi, np.pi, 181), [-np.pi / 2, np.pi / 2])
    T_tool = dec.decoupling_field_toolbox(grid, robot)
    T_fast = dec.DecouplingField(robot).field(grid)
    assert np.max(np.abs(T_tool - T_fast)) <= 1e-12 * np.max(np.abs(T_fast))
    T_scalar = dec.decoupling_field_toolbox(0.3, robot)
    assert T_scalar.shape == (3, 3)
    assert np.max(np.abs(T_scalar - dec.DecouplingField(robot).field(0.3))) <= 1e-12 * np.max(np.abs(T_scalar))


def test_partition_subspaces_are_the_single_axis_accelerations(robot):
    # im g cap V*_theta must be span(e_6): pure angular acceleration (eq. 33 read with V*)
    g = g_theta(0.4, robot)
    A = A_matrix(robot)
    img = geo.image(g)
    C_x_cap_C_y = geo.kernel(np.array([[1.0, 0, 0, 0, 0, 0], [0, 0, 1.0, 0, 0, 0]]))
    assert geo.dim(geo.intersection(img, C_x_cap_C_y)) == 3  # the literal reading is all of im g
    V = geo.maxV(A, img, C_x_cap_C_y)
    assert geo.subspaces_equal(V, np.eye(6)[:, [4, 5]])
    assert geo.subspaces_equal(geo.intersection(img, V), np.eye(6)[:, [5]])


def _simulate(robot, u, theta0, t_end=1.5):
    field = dec.DecouplingField(robot)
    A = A_matrix(robot)

    def rhs(_, X):
        return A @ X + g_theta(X[4], robot) @ (field.field(X[4]) @ u)

    X0 = np.zeros(6)
    X0[4] = theta0
    return solve_ivp(rhs, (0.0, t_end), X0, rtol=1e-10, atol=1e-12, dense_output=True)


def _first_order(acc, damping, t):
    """Position of x'' = acc - damping x' from rest."""
    return acc / damping * (t - (1.0 - np.exp(-damping * t)) / damping)


def test_x_command_moves_only_x_from_a_turned_heading(robot):
    sol = _simulate(robot, np.array([0.4, 0.0, 0.0]), theta0=np.pi / 2)
    t = np.linspace(0.0, 1.5, 50)
    X = sol.sol(t)
    assert np.allclose(X[0], _first_order(0.4, robot.k_x / robot.M, t), atol=1e-8)
    assert np.max(np.abs(X[2])) < 1e-8 and np.max(np.abs(X[4] - np.pi / 2)) < 1e-8


def test_rotation_command_turns_through_pi_over_2_without_moving(robot):
    sol = _simulate(robot, np.array([0.0, 0.0, 6.0]), theta0=0.0, t_end=2.0)
    t = np.linspace(0.0, 2.0, 80)
    X = sol.sol(t)
    theta = _first_order(6.0, robot.k_theta / robot.J, t)
    assert theta[-1] > np.pi  # passes pi/2 and pi
    assert np.allclose(X[4], theta, atol=1e-8)
    assert np.max(np.abs(X[[0, 2]])) < 1e-8


def test_check_reports_failure_for_a_wrong_field(robot, monkeypatch):
    monkeypatch.setattr(dec.DecouplingField, "field",
                        lambda self, theta: np.broadcast_to(self.T0, np.shape(theta) + (3, 3)))
    bad = dec.check_decoupling(robot, n_theta=90)
    assert bad.max_residual > 0.5
    assert not bad.passed
    assert not all(c.passed for c in bad.conditions if c.equation in ("(12)", "(14)"))


@pytest.mark.parametrize("theta", [np.nan, np.inf, [[0.0]]])
def test_bad_theta_raises(robot, theta):
    with pytest.raises(dec.DecouplingError, match="theta"):
        dec.DecouplingField(robot).field(theta)


def test_bad_grid_size_raises():
    with pytest.raises(dec.DecouplingError, match="n_theta"):
        dec.theta_grid(1)


def test_forces_are_the_field_times_u(robot):
    """`forces` (Python floats, the controller's per-tick path) is field(theta) @ u, to 1e-12."""
    field = dec.DecouplingField(robot)
    rng = np.random.default_rng(3)
    for theta in np.concatenate((dec.theta_grid(36), rng.uniform(-50.0, 50.0, 8))):
        u = rng.normal(0.0, 2.0, 3)
        fast = field.forces(float(theta), u.tolist())
        reference = field.field(theta) @ u
        assert all(type(v) is float for v in fast)
        np.testing.assert_allclose(fast, reference, rtol=0.0, atol=1e-12 * np.abs(reference).max())
