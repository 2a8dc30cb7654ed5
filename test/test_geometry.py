"""Geometric toolbox: textbook cases with known answers and property-based checks (hypothesis)."""

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.geometric import subspaces as geo

pytestmark = pytest.mark.unit

PROPS = settings(max_examples=60, deadline=None)


def span(*vectors):
    return np.column_stack([np.asarray(v, dtype=float) for v in vectors])


def e(n, *idx):
    return np.eye(n)[:, list(idx)]


# --- textbook cases ----------------------------------------------------------


def test_double_integrator_is_reachable_and_has_no_zero():
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    assert geo.dim(geo.minI(A, B)) == 2
    assert geo.dim(geo.maxV(A, B, geo.kernel(C))) == 0  # relative degree 2 = n: no invariant zeros
    assert geo.subspaces_equal(geo.minS(A, geo.kernel(C), B), np.eye(2))  # B + A(B cap ker C) = R^2


def test_triple_chain_z_sequence_grows_one_step_at_a_time():
    A = np.diag([1.0, 1.0], 1)
    B = e(3, 2)
    C = np.array([[1.0, 0.0, 0.0]])
    Z = geo.z_sequence(A, B, geo.kernel(C))
    assert [geo.dim(z) for z in Z] == [1, 2, 3, 3]
    assert geo.subspaces_equal(Z[1], e(3, 1, 2))


def test_uncontrollable_mode_is_outside_minI():
    A = np.diag([-1.0, -2.0, -3.0])
    B = np.array([[1.0], [1.0], [0.0]])
    R = geo.minI(A, B)
    assert geo.subspaces_equal(R, e(3, 0, 1))
    assert not geo.is_subspace(e(3, 2), R)


def test_transmission_zero_gives_one_dimensional_maxV():
    # (s + 1) / s^2: x1' = x2, x2' = u, y = x1 + x2; V* = ker C, and A V* + B = ...
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 1.0]])
    V = geo.maxV(A, B, geo.kernel(C))
    assert geo.subspaces_equal(V, span([1.0, -1.0]))
    # on V* with the friend u = F x the state moves with the zero: x' = -x
    x = np.array([1.0, -1.0])
    u = -(C @ A @ x) / (C @ B)  # keeps y' = 0
    assert np.allclose(A @ x + B[:, 0] * u, -x)


def test_decoupled_block_system():
    # two independent double integrators; the second input only reaches the second block
    A = np.kron(np.eye(2), np.array([[0.0, 1.0], [0.0, 0.0]]))
    B = e(4, 1, 3)
    C1 = np.array([[1.0, 0.0, 0.0, 0.0]])
    assert geo.subspaces_equal(geo.minI(A, B[:, 1:]), e(4, 2, 3))
    assert geo.subspaces_equal(geo.maxV(A, B, geo.kernel(C1)), e(4, 2, 3))
    # the second block is A-invariant and invisible in x1 whatever the input
    assert geo.subspaces_equal(geo.maxV(A, B[:, :1], geo.kernel(C1)), e(4, 2, 3))
    C13 = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    assert geo.dim(geo.maxV(A, B[:, :1], geo.kernel(C13))) == 0


def test_basic_operations_on_coordinate_subspaces():
    V, W = e(4, 0, 1), e(4, 1, 2)
    assert geo.subspaces_equal(geo.intersection(V, W), e(4, 1))
    assert geo.subspaces_equal(geo.subspace_sum(V, W), e(4, 0, 1, 2))
    assert geo.subspaces_equal(geo.orthogonal_complement(V), e(4, 2, 3))
    assert geo.dim(geo.intersection(e(4, 0), e(4, 3))) == 0
    shift = np.diag(np.ones(3), 1)  # e_{k+1} -> e_k
    assert geo.subspaces_equal(geo.inverse_image(shift, e(4, 0)), e(4, 0, 1))
    assert geo.subspaces_equal(geo.apply_map(shift, e(4, 0, 2)), e(4, 1))


def test_tolerance_is_overridable():
    M = np.array([[1.0, 0.0], [0.0, 1e-9]])
    assert geo.dim(geo.image(M)) == 2
    assert geo.dim(geo.image(M, rtol=1e-6)) == 1


def test_stacks_work_element_by_element_and_reject_unequal_dimensions():
    angles = np.linspace(0.0, 3.0, 7)
    V = np.stack([span([np.cos(a), np.sin(a), 0.0]) for a in angles])
    plane = e(3, 0, 1)
    assert geo.image(V).shape == (7, 3, 1)
    assert np.all(geo.inclusion_residual(V, plane) < 1e-15)
    assert geo.intersection(V, plane).shape == (7, 3, 1)
    mixed = np.stack([np.eye(3)[:, :2], np.column_stack((np.eye(3)[:, 0], np.eye(3)[:, 0]))])
    with pytest.raises(geo.GeometryError, match="varies"):
        geo.image(mixed)


@pytest.mark.parametrize(
    "call",
    [
        lambda: geo.image([1.0, 2.0]),
        lambda: geo.kernel([[np.nan, 1.0]]),
        lambda: geo.minI(np.ones((2, 3)), np.ones((2, 1))),
        lambda: geo.maxV(np.eye(3), np.ones((2, 1)), np.eye(3)),
        lambda: geo.z_sequence(np.eye(2), np.ones((2, 1)), np.eye(2), steps=-1),
    ],
)
def test_bad_input_raises_geometry_error(call):
    with pytest.raises(geo.GeometryError):
        call()


# --- property-based ----------------------------------------------------------


@st.composite
def systems(draw, max_n=6):
    n = draw(st.integers(2, max_n))
    m = draw(st.integers(1, n))
    p = draw(st.integers(1, n))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    return rng.standard_normal((n, n)), rng.standard_normal((n, m)), rng.standard_normal((p, n)), rng


@st.composite
def subspace_pairs(draw):
    """Two random subspaces of R^n sharing a random common part (so the intersection is not trivial)."""
    n = draw(st.integers(2, 6))
    k = draw(st.integers(0, n))
    a = draw(st.integers(0, n - k))
    b = draw(st.integers(0, n - k - a))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    common = rng.standard_normal((n, k))
    V = np.hstack((common, rng.standard_normal((n, a))))
    W = np.hstack((rng.standard_normal((n, b)), common))
    return V, W, k


@PROPS
@given(subspace_pairs())
def test_dimension_formula(pair):
    V, W, k = pair
    dv, dw = geo.dim(geo.image(V)), geo.dim(geo.image(W))
    assert geo.dim(geo.subspace_sum(V, W)) + geo.dim(geo.intersection(V, W)) == dv + dw
    assert geo.dim(geo.intersection(V, W)) == k  # generic: only the common part
    assert geo.dim(geo.subspace_sum(V, W)) == np.linalg.matrix_rank(np.hstack((V, W)))


@PROPS
@given(systems())
def test_minI_is_invariant_contains_B_and_matches_kalman_rank(system):
    A, B, _, _ = system
    R = geo.minI(A, B)
    assert geo.is_subspace(B, R)
    assert geo.is_subspace(A @ R, R)
    n = A.shape[0]
    kalman = np.hstack([np.linalg.matrix_power(A, k) @ B for k in range(n)])
    assert geo.dim(R) == np.linalg.matrix_rank(kalman)


@PROPS
@given(st.integers(2, 6), st.integers(0, 2**32 - 1))
def test_minI_of_a_system_with_an_uncontrollable_part(n, seed):
    rng = np.random.default_rng(seed)
    r = int(rng.integers(1, n))
    # block upper-triangular in hidden coordinates: the last n - r states are not reachable
    A = rng.standard_normal((n, n))
    A[r:, :r] = 0.0
    B = np.vstack((rng.standard_normal((r, 2)), np.zeros((n - r, 2))))
    S, _ = np.linalg.qr(rng.standard_normal((n, n)))
    R = geo.minI(S @ A @ S.T, S @ B)
    assert geo.subspaces_equal(R, S[:, :r])


@PROPS
@given(subspace_pairs())
def test_inclusion_agrees_with_rank_test(pair):
    V, W, _ = pair
    for X, Y in ((V, W), (W, V), (V[:, : max(V.shape[1] - 1, 0)], V)):
        rank_says = np.linalg.matrix_rank(np.hstack((Y, X))) == np.linalg.matrix_rank(Y)
        assert geo.is_subspace(X, Y) == rank_says


@PROPS
@given(st.integers(1, 6), st.integers(0, 6), st.integers(0, 2**32 - 1))
def test_random_bases_of_one_subspace_compare_equal(n, k, seed):
    k = min(k, n)
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((n, k))
    G = rng.standard_normal((k, k)) + 3.0 * np.eye(k)  # invertible change of basis
    assert geo.subspaces_equal(V, V @ G)
    assert geo.subspaces_equal(V, np.hstack((V @ G, V[:, :1] if k else np.zeros((n, 0)))))
    if 0 < k < n:
        assert not geo.subspaces_equal(V, V[:, :-1])


@PROPS
@given(st.integers(1, 6), st.integers(1, 6), st.integers(0, 6), st.integers(0, 2**32 - 1))
def test_kernel_image_and_complements(p, n, r, seed):
    rng = np.random.default_rng(seed)
    r = min(r, p, n)
    M = rng.standard_normal((p, r)) @ rng.standard_normal((r, n))
    K, Im = geo.kernel(M), geo.image(M)
    assert geo.dim(K) + geo.dim(Im) == n
    assert np.allclose(M @ K, 0.0, atol=1e-12)
    assert geo.subspaces_equal(K, geo.orthogonal_complement(geo.image(M.T)))
    assert geo.subspaces_equal(geo.orthogonal_complement(Im), geo.kernel(M.T))
    # independent truth: scipy
    assert geo.subspaces_equal(Im, sla.orth(M)) if r else geo.dim(Im) == 0
    assert geo.subspaces_equal(K, sla.null_space(M)) if r < n else geo.dim(K) == 0


@PROPS
@given(systems())
def test_maxV_is_controlled_invariant_in_E_and_dual_to_minS(system):
    A, B, C, _ = system
    E = geo.kernel(C)
    V = geo.maxV(A, B, E)
    assert geo.is_subspace(V, E)
    assert np.max(geo.inclusion_residual(A @ V, geo.subspace_sum(V, B))) <= 1e-10 * np.linalg.norm(A, 2)
    # duality: maxV(A, B, E)^perp = minS(A^T, B^perp, E^perp)
    S = geo.minS(A.T, geo.orthogonal_complement(B), geo.orthogonal_complement(E))
    assert geo.subspaces_equal(geo.orthogonal_complement(V), S)
    # S* is conditioned invariant and contains its B
    Sc = geo.minS(A, E, B)
    assert geo.is_subspace(B, Sc)
    assert np.max(geo.inclusion_residual(A @ geo.intersection(Sc, E), Sc)) <= 1e-10 * np.linalg.norm(A, 2)


@PROPS
@given(st.integers(0, 2**32 - 1), st.integers(1, 3), st.integers(0, 3))
def test_maxV_recovers_a_planted_controlled_invariant(seed, k, extra):
    """V* of a system with a planted zero dynamics of dimension k equals the planted subspace."""
    rng = np.random.default_rng(seed)
    # chain of length `extra + 1` from u to y plus k zero-dynamics states driven by y:
    # the largest controlled invariant in ker C is the zero-dynamics part.
    n = k + extra + 1
    A = np.zeros((n, n))
    A[:k, :k] = rng.standard_normal((k, k))
    A[:k, k] = rng.standard_normal(k)  # zero dynamics driven by y
    for i in range(k, n - 1):
        A[i, i + 1] = 1.0
    A[n - 1] = rng.standard_normal(n)
    B = np.zeros((n, 1))
    B[n - 1, 0] = 1.0
    C = np.zeros((1, n))
    C[0, k] = 1.0
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V = geo.maxV(Q @ A @ Q.T, Q @ B, geo.kernel(C @ Q.T))
    assert geo.subspaces_equal(V, Q[:, :k])


# --- the algorithms against the textbook recursions written with scipy.linalg.orth / null_space ----------


def _sp_sum(*Vs):
    return sla.orth(np.hstack(Vs))


def _sp_cap(V, W):
    if V.shape[1] == 0 or W.shape[1] == 0:
        return np.zeros((V.shape[0], 0))
    Q, Qw = sla.orth(V), sla.orth(W)
    N = sla.null_space(np.hstack((Q, -Qw)))
    return sla.orth(Q @ N[: Q.shape[1]]) if N.shape[1] else np.zeros((V.shape[0], 0))


def _sp_inverse_image(A, V):
    Vperp = sla.null_space(V.T) if V.shape[1] else np.eye(A.shape[0])
    return sla.null_space(Vperp.T @ A) if Vperp.shape[1] else np.eye(A.shape[0])


def _sp_maxV(A, B, E):
    V = sla.orth(E)
    for _ in range(A.shape[0] + 1):
        V = _sp_cap(E, _sp_inverse_image(A, _sp_sum(V, B)))
    return V


def _sp_minS(A, C, B):
    S = sla.orth(B)
    for _ in range(A.shape[0] + 1):
        S = _sp_sum(B, A @ _sp_cap(S, C))
    return S


@pytest.mark.slow
@PROPS
@given(systems())
def test_algorithms_equal_the_recursions_of_an_independent_implementation(system):
    """maxV, minS, minI and z_sequence (private cores on their own intermediates) against the same
    recursions on scipy's orth / null_space, iterated to their fixed points.
    """
    A, B, C, _ = system
    n = A.shape[0]
    E = sla.null_space(C)
    assert geo.subspaces_equal(geo.maxV(A, B, E), _sp_maxV(A, B, E))
    assert geo.subspaces_equal(geo.minS(A, E, B), _sp_minS(A, E, B))
    R = sla.orth(B)
    for _ in range(n):
        R = _sp_sum(R, A @ R)
    assert geo.subspaces_equal(geo.minI(A, B), R)
    F = sla.orth(np.hstack((B, A @ B)))
    Z = geo.z_sequence(A, B, E, F)
    ref = sla.orth(B)
    for Zj in Z:
        assert geo.subspaces_equal(Zj, ref)
        ref = _sp_sum(B, A @ _sp_cap(_sp_cap(ref, F), E))
