"""The constrained mode's screen: a proof in a few float operations that the closed form (56) meets every limit.

A tick whose full check (`constrained.ConstrainedMPC`) passed becomes the
reference; a later tick passes the screen if max |rows_r| plus a rigorous
bound of the rows' change since the reference stays below 1. The bound is
linear in the change of q = T p: eq. (56)'s bracket Y_d - G_p x - F_2p u(k-1)
(axis by axis), x', y', theta, theta', u(k-1) and the start currents i_0
(translating the positions changes no signal nor angle). Its per-tick cost
is one unrolled loop over the periods on Python floats: no numpy call.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from operator import mul, sub

import numpy as np

from robotino_geom_mpc.control.mpc import DecoupledMPC

__all__ = ["LimitScreen"]

SCREEN_MARGIN = 1e-9  # the screen passes only rows proven below 1 - this (round-off of the rows ~1e-13)
SCREEN_W_STEP = 0.5  # [rad/s] largest change of theta' since the reference the screen accepts


class LimitScreen:
    """Bound of the constraint rows' change between ticks, from their reference tick.

    Parameters
    ----------
    mpc
        The unconstrained MPCs (G_p, F_2p of eq. 56's bracket).
    angles, signals, rows
        The rows' fixed matrices on the parameter vector p of `constrained.ConstrainedMPC`:
        the factors' angles A (cos(A p)), the extended signals at the closed form M (M p)
        and B_ext (rows = B_ext (factors * signals)).
    n_sig, n_rate
        Signals without theta' parts, and of them the rate rows that carry theta' (they come last).
    """

    def __init__(
        self, mpc: DecoupledMPC, angles: np.ndarray, signals: np.ndarray, rows: np.ndarray, n_sig: int, n_rate: int
    ) -> None:
        N = self.N = mpc.G_p.shape[1]
        T = np.zeros((3 * N + 10, 3 * N + 13))
        for a in range(3):
            errors = np.arange(a * N, (a + 1) * N)
            T[errors, np.arange(a, 3 * N, 3)] = 1.0
            T[errors, 3 * N + 2 * a : 3 * N + 2 * a + 2] = -mpc.G_p[a]
            T[errors, 3 * N + 6 + a] = -mpc.F_2p[a]
        T[3 * N :, [3 * N + 1, 3 * N + 3, *range(3 * N + 4, 3 * N + 12)]] = np.eye(10)
        self._brackets = T[: 3 * N].reshape(3, N, -1).swapaxes(0, 1).reshape(3 * N, -1)  # in Y_d's order
        # (G_p position, G_p velocity, F_2p) of each bracket entry, in Y_d's order (period by period)
        self._free = np.stack([np.column_stack((mpc.G_p[a], mpc.F_2p[a])) for a in range(3)], 1).reshape(-1, 3)
        back = np.linalg.pinv(T)
        abs_signals, abs_angles = np.abs(signals @ back), np.abs(angles @ back)
        self._n_sig = n_sig
        self._B = np.abs(rows)
        self._angles = np.concatenate((abs_angles, abs_angles[n_sig - n_rate :]))  # theta' rows: the rates'
        self._cos = self._B[:, :n_sig] @ abs_signals[:n_sig]
        self._theta = self._B[:, n_sig:] @ abs_signals[n_sig:]
        self.reset()

    def reset(self) -> None:
        """Drop the reference: the screen passes nothing until `set_reference`."""
        self._ref: tuple[float, float] | None = None

    def passes(
        self, X: Sequence[float], u_prev: Sequence[float], Y_d: Sequence[Sequence[float]], i_start: Sequence[float]
    ) -> bool:
        """Whether the closed form provably meets every limit at this tick (False without a reference)."""
        return self._ref is not None and self._change(X, u_prev, Y_d, i_start) <= self._ref[1]

    def _change(
        self, X: Sequence[float], u_prev: Sequence[float], Y_d: Sequence[Sequence[float]], i_start: Sequence[float]
    ) -> float:
        """sum_j c_j |q_j - q_r,j| (`set_reference`) from the floats; inf for a larger change of theta'."""
        px, vx, py, vy, theta, w = X
        assert self._ref is not None  # `passes` checks
        if not abs(w - self._ref[0]) <= SCREEN_W_STEP:
            return math.inf
        ux, uy, ut = u_prev
        i_x, i_y, i_theta = i_start.tolist() if isinstance(i_start, np.ndarray) else i_start  # no numpy scalars
        change = 0.0  # per entry c_j q_j - c_j q_r,j = c_j y_j - (c G_p)_j (p_j, v_j) - (c F_2p)_j u_j - c_j q_r,j
        for (yx, yy, yt), (a, b, c, d, e), (f, g, h, i, j), (k, l, m, n, o) in zip(Y_d, *self._weights[0]):
            change += (abs(a * yx - b * px - c * vx - d * ux - e) + abs(f * yy - g * py - h * vy - i * uy - j)
                       + abs(k * yt - l * theta - m * w - n * ut - o))
        rest, rest_ref = self._weights[1:]
        others = (vx, vy, theta, w, ux, uy, ut, i_x, i_y, i_theta)
        return change + sum(map(mul, rest, map(abs, map(sub, others, rest_ref))))

    def set_reference(
        self,
        X: Sequence[float],
        u_prev: Sequence[float],
        i_start: Sequence[float],
        p: np.ndarray,
        signals: np.ndarray,
        rows_max: float,
    ) -> None:
        """Make a tick whose full check has just passed the reference: its p, signals at z* and largest |row|.

        The screen passes a tick if max |rows_r| + sum_j c_j |q_j - q_r,j| <= 1 - `SCREEN_MARGIN`: row i is
        sum_k B_ik f_k s_k (f: cos of the angles, or theta' times the rate rows'; s: signals at z*), |f s - f_r s_r|
        <= |f| |s - s_r| + |f - f_r| |s_r|, |cos a - cos b| <= |a - b|, |f| <= 1 or |theta'_r| + `SCREEN_W_STEP`
        (a larger change of theta' fails): c_j, the largest over the rows, bounds the change per |q_j - q_r,j|.
        """
        N, n_sig, B, s, w = self.N, self._n_sig, self._B, np.abs(signals), abs(X[5])
        scale = np.concatenate((s[:n_sig], w * s[n_sig:]))
        c = self._cos + (w + SCREEN_W_STEP) * self._theta + (B * scale) @ self._angles
        c[:, 3 * N + 3] += B[:, n_sig:] @ s[n_sig:]
        c = c.max(axis=0)
        c_brackets = c[: 3 * N].reshape(3, N).T.ravel()  # Y_d's order: period by period
        weights = np.column_stack((c_brackets, c_brackets[:, None] * self._free, c_brackets * (self._brackets @ p)))
        per_axis = [list(map(tuple, weights[a::3].tolist())) for a in range(3)]  # (c, c G_p, c F_2p, c q_r), period j
        others = [X[1], X[3], X[4], X[5], *u_prev, *map(float, i_start)]
        self._weights = per_axis, c[3 * N :].tolist(), others
        self._ref = (X[5], 1.0 - SCREEN_MARGIN - rows_max)
