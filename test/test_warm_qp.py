"""control.warm_qp.WarmDaqp against quadprog (Goldfarb-Idnani, an independent dual active-set code), warm and cold."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.control.warm_qp import WarmDaqp

pytestmark = pytest.mark.unit

quadprog = pytest.importorskip("quadprog")


def _quadprog(P, G, lower, upper):
    """min 1/2 d'Pd, lower <= G d <= upper, by quadprog (rows as G d >= lower and -G d >= -upper)."""
    return quadprog.solve_qp(P, np.zeros(len(P)), np.vstack((G, -G)).T, np.concatenate((lower, -upper)))[0]


def _problem(rng, n, m, shift):
    """A positive definite P, rows G, a point d0 and rows s in (-0.9, 0.9) at it: r = s - G d0 keeps d0 feasible.

    d0 is scaled to max |G d0| = `shift`: above 1.9 a row binds at the unconstrained optimum d = 0.
    """
    root = rng.normal(size=(n, n))
    P = root @ root.T + n * np.eye(n)
    G = rng.normal(size=(m, n))
    d0 = rng.normal(size=n)
    return P, G, d0 * (shift / np.abs(G @ d0).max()), rng.uniform(-0.9, 0.9, m)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 12), rows=st.integers(1, 4), shift=st.floats(0.0, 3.0),
       drift=st.floats(1e-4, 0.3))
def test_warm_solves_equal_quadprog_along_a_sequence_and_after_reset(seed, n, rows, shift, drift):
    """A sequence of slowly changing QPs (warm starts carry over), then a reset (cold): each d equals quadprog's."""
    rng = np.random.default_rng(seed)
    m = rows * n
    P, G, d0, s = _problem(rng, n, m, shift)
    solver = WarmDaqp(P, m)
    bound = 0
    for k in range(6):
        if k == 4:
            solver.reset()
        if k:
            G = G + drift * rng.normal(size=G.shape)
        r = s - G @ d0
        lower, upper = -1.0 - r, 1.0 - r
        ok, d = solver.solve(G, lower, upper)
        assert ok
        expected = _quadprog(P, G, lower, upper)
        np.testing.assert_allclose(d, expected, rtol=0, atol=1e-8 * max(1.0, float(np.abs(expected).max())))
        assert np.all(G @ d <= upper + 1e-9) and np.all(G @ d >= lower - 1e-9)
        bound += int(np.any(np.abs(r) > 1.0))
    if shift > 1.9:
        assert bound  # not vacuous: at k = 0 a row binds at d = 0 by construction


def test_a_failed_solve_starts_the_next_cold_and_it_is_solved():
    """An infeasible QP (two equal rows with disjoint ranges) fails; the next, feasible one is solved to quadprog's."""
    rng = np.random.default_rng(3)
    P, G, d0, s = _problem(rng, 4, 8, 2.0)
    r = s - G @ d0
    solver = WarmDaqp(P, 8)
    clash = G.copy()
    clash[1] = clash[0]
    ok, _ = solver.solve(clash, np.r_[0.5, -1.0, np.full(6, -1.0)], np.r_[1.0, -0.5, np.full(6, 1.0)])
    assert not ok
    lower, upper = -1.0 - r, 1.0 - r
    ok, d = solver.solve(G, lower, upper)
    assert ok
    np.testing.assert_allclose(d, _quadprog(P, G, lower, upper), rtol=0, atol=1e-9)
