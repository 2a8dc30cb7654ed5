"""Functional-controllability orders (Section IV): projection condition (38) vs Markov parameters."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.geometric import functional as fc
from robotino_geom_mpc.geometric import subspaces as geo
from robotino_geom_mpc.geometric.decoupling import B_decoupled
from robotino_geom_mpc.model.dynamics import A_matrix, C_matrix, coupled_rhs
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import preset_file

pytestmark = pytest.mark.unit

PROPS = settings(max_examples=60, deadline=None)


@pytest.fixture(scope="module", params=("robotino3", "robotino2"))
def robot(request):
    return load_params(preset_file(request.param))[0]


def chains(degrees, rng, extra=0):
    """Integrator chains of the given lengths (one per input/output), extra hidden states,
    feedback and output injection (which keep the structure at infinity), rotated by an orthogonal map.
    """
    p = len(degrees)
    n = int(sum(degrees)) + extra
    A, B, C = np.zeros((n, n)), np.zeros((n, p)), np.zeros((p, n))
    k = 0
    for i, r in enumerate(degrees):
        A[k : k + r - 1, k + 1 : k + r] = np.eye(r - 1)
        B[k + r - 1, i] = 1.0
        C[i, k] = 1.0
        k += r
    A[k:, k:] = rng.standard_normal((extra, extra))
    A += B @ rng.standard_normal((p, n)) + rng.standard_normal((n, p)) @ C
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    mix_in = rng.standard_normal((p, p)) + 3.0 * np.eye(p)
    mix_out = rng.standard_normal((p, p)) + 3.0 * np.eye(p)
    return Q @ A @ Q.T, Q @ B @ mix_in, mix_out @ C @ Q.T


def test_paper_x_axis_steps_45_to_47(robot):
    A, B, C = A_matrix(robot), B_decoupled(), C_matrix()
    F_x = fc.axis_subspace("x")
    Z = geo.z_sequence(A, B, geo.kernel(C[:1]), F_x)
    e = np.eye(6)
    assert geo.subspaces_equal(geo.intersection(F_x, Z[0]), e[:, [1]])  # eq. (45)
    assert geo.subspaces_equal(geo.intersection(F_x, Z[1]), F_x)  # eq. (47)
    assert fc.functional_order(A, B, C[:1], F_x) == 2


def test_orders_of_the_robotino(robot):
    summary = fc.functional_controllability(robot)
    assert summary["orders"] == {"mechanical": 2, "drive": 1, "cascade": 3}
    assert summary["details"]["drive"]["motor speed"] == {"projection": 2, "markov": 2}


def test_cascade_matrices_are_the_jacobian_of_the_coupled_plant(robot):
    for theta in (0.0, 0.7, np.pi / 2, -2.0):
        A_c, B_c, C_c = fc.cascade_matrices(theta, robot)
        z0 = np.zeros(9)
        z0[4] = theta
        h = 1e-6
        u0 = np.zeros(3)
        J = np.column_stack([(coupled_rhs(z0 + h * d, u0, robot) - coupled_rhs(z0 - h * d, u0, robot)) / (2 * h)
                             for d in np.eye(9)])
        Ju = np.column_stack([(coupled_rhs(z0, h * d, robot) - coupled_rhs(z0, -h * d, robot)) / (2 * h)
                              for d in np.eye(3)])
        assert np.allclose(A_c, J, rtol=1e-6, atol=1e-6 * np.max(np.abs(J)))
        assert np.allclose(B_c, Ju, rtol=1e-6)
        assert fc.functional_order(A_c, B_c, C_c) == fc.markov_order(A_c, B_c, C_c) == 3


def test_cascade_voltage_to_position_relative_degree_three_by_simulation(robot):
    """Independent check: a voltage step moves the position like t^3 at first (the third derivative jumps)."""
    U = np.array([1.0, -0.5, 0.2])
    h = 1e-5  # well below L / R = 1.5 ms
    z = np.zeros(9)
    z[4] = 0.3
    positions = []
    for _ in range(4):  # RK4 from rest
        k1 = coupled_rhs(z, U, robot)
        k2 = coupled_rhs(z + h / 2 * k1, U, robot)
        k3 = coupled_rhs(z + h / 2 * k2, U, robot)
        k4 = coupled_rhs(z + h * k3, U, robot)
        z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        positions.append(z[[0, 2, 4]] - [0.0, 0.0, 0.3])
    positions = np.array(positions)
    # y(t) ~ c t^3: y(2h) / y(h) = 8 to first order
    ratio = positions[1] / positions[0]
    assert np.allclose(ratio, 8.0, rtol=5e-3)
    A_c, B_c, C_c = fc.cascade_matrices(0.3, robot)
    assert np.allclose(positions[0], C_c @ A_c @ A_c @ B_c @ U * h**3 / 6, rtol=5e-3)


@pytest.mark.parametrize("rho", [1, 2, 3, 4, 5])
def test_single_chain_relative_degree(rho):
    rng = np.random.default_rng(rho)
    A, B, C = chains([rho], rng, extra=2)
    assert fc.functional_order(A, B, C) == fc.markov_order(A, B, C) == rho
    # the brief's rule: the smallest k with C A^(k-1) B of full row rank
    k = next(k for k in range(1, 10) if np.linalg.matrix_rank(C @ np.linalg.matrix_power(A, k - 1) @ B, tol=1e-9) == 1)
    assert k == rho


@PROPS
@given(st.lists(st.integers(1, 4), min_size=1, max_size=3), st.integers(0, 2), st.integers(0, 2**32 - 1))
def test_vector_relative_degrees_give_the_largest(degrees, extra, seed):
    A, B, C = chains(degrees, np.random.default_rng(seed), extra)
    assert fc.functional_order(A, B, C) == max(degrees)
    assert fc.markov_order(A, B, C) == max(degrees)


@PROPS
@given(st.integers(2, 6), st.integers(1, 3), st.integers(1, 3), st.booleans(), st.integers(0, 2**32 - 1))
def test_routes_agree_on_random_systems(n, m, p, cb_zero, seed):
    rng = np.random.default_rng(seed)
    A, B, C = rng.standard_normal((n, n)), rng.standard_normal((n, m)), rng.standard_normal((p, n))
    if cb_zero and p < n:  # B inside ker C: relative degree at least 2
        B = geo.kernel(C) @ rng.standard_normal((n - p, m))
    assert fc.functional_order(A, B, C) == fc.markov_order(A, B, C)


def test_more_outputs_than_inputs_is_not_functionally_controllable():
    A = np.diag([1.0, 1.0], 1)
    B = np.array([[0.0], [0.0], [1.0]])
    C = np.eye(3)[:2]
    assert fc.functional_order(A, B, C) is None
    assert fc.markov_order(A, B, C) is None


@pytest.mark.parametrize(
    "args",
    [
        (np.ones((2, 3)), np.ones((2, 1)), np.ones((1, 2))),
        (np.eye(2), np.ones((3, 1)), np.ones((1, 2))),
        (np.eye(2), np.ones((2, 1)), np.ones((1, 3))),
        (np.eye(2) * np.nan, np.ones((2, 1)), np.ones((1, 2))),
    ],
)
def test_bad_systems_raise(args):
    with pytest.raises(fc.FunctionalError):
        fc.functional_order(*args)
    with pytest.raises(fc.FunctionalError):
        fc.markov_order(*args)


def test_bad_order_bound_and_axis_raise():
    with pytest.raises(fc.FunctionalError, match="max_order"):
        fc.markov_order(np.eye(2), np.ones((2, 1)), np.ones((1, 2)), max_order=0)
    with pytest.raises(fc.FunctionalError, match="axis"):
        fc.axis_subspace("z")
