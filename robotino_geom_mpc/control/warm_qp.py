"""DAQP on the constrained mode's QP, set up once and warm-started from its last active set."""

from __future__ import annotations

import daqp
import numpy as np

__all__ = ["WarmDaqp"]

_DAQP_OPTIMAL = 1  # DAQP exitflag of an optimal solution
_PRIMAL_TOL = 1e-11  # DAQP primal feasibility tolerance on the scaled rows (its default 1e-6 moves u by ~1e-5)


class WarmDaqp:
    """min 1/2 d'Pd subject to lower <= G d <= upper (two-sided rows), by DAQP (dual active set).

    The model is set up once (its workspace, the factor of the fixed P); each
    `solve` updates G and the bounds, and DAQP starts from the active set of
    its last solve, unless `reset` (or a failed solve) asked for a cold start.

    Parameters
    ----------
    P
        The fixed Hessian (positive definite), (n, n).
    rows
        Number of constraint rows m.
    """

    def __init__(self, P: np.ndarray, rows: int) -> None:
        n = len(P)
        # DAQP keeps pointers to the arrays it is given: the Hessian and the (zero) cost for the model's life,
        # G, the bounds and `sense` until the next update gives others (`solve` keeps those)
        self._setup = (P, np.zeros(n), np.zeros((rows, n)), np.ones(rows), -np.ones(rows), np.zeros(rows, np.int32))
        self._model = daqp.Model()
        self._model.setup(*self._setup)
        self._model.settings = {"primal_tol": _PRIMAL_TOL}
        self._rows = rows
        self.reset()

    def reset(self) -> None:
        """Start the next solve from the empty active set."""
        self._cold: np.ndarray | None = np.zeros(self._rows, dtype=np.int32)

    def solve(self, G: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[bool, np.ndarray]:
        """(solved, d) for this G and bounds; the next solve starts cold after a failure."""
        if self._cold is None:  # without `sense`, DAQP starts from the active set of its last solve
            self._model.update(A=G, bupper=upper, blower=lower)
        else:
            self._sense = self._cold  # kept: DAQP reads its last `sense` array until it gets another
            self._model.update(A=G, bupper=upper, blower=lower, sense=self._sense)
        self._data = (G, upper, lower)  # alive until the next update
        d, _, exitflag, _ = self._model.solve()
        ok = exitflag == _DAQP_OPTIMAL
        self._cold = None if ok else np.zeros(self._rows, dtype=np.int32)
        return ok, d
