"""Three decoupled position MPCs in the Delta-u form, Section V (eqs. 48-56).

After the decoupling field T(theta) (eqs. 33-37) the body is three double
integrators with viscous friction, one per axis a in (x, y, theta):

    pos_a'' = -(k_a / m_a) pos_a' + u_a,   k_a / m_a in (k_x/M, k_y/M, k_theta/J),

with state x_a = (pos_a, pos_a') (the blocks of eq. 3) and output H = (1, 0).
Each axis is discretised exactly under a zero-order hold of period Ts, put in
the Delta-u form (48)-(49) and predicted over N steps (50)-(53), with the
corrected F_1p and F_2p of erratum 3. The receding-horizon law applies only
the first component of the closed form (56), so only the first row of its
gain is kept and one control step is a few dot products for the three axes.

`closed_loop_poles` and `check_closed_loop` give the poles of that receding-
horizon law on the nominal axis model: a weight set (q/r small for the
horizon) can make the loop unstable, which a controller must refuse.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import chain
import math
from operator import mul

import numpy as np

from robotino_geom_mpc.geometric.decoupling import AXES
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.params.specs import ControlParams, ParamError, RobotinoParams

__all__ = ["MPCError", "UnstableClosedLoopError", "axis_dampings", "discretize_axis", "prediction_matrices",
           "DecoupledMPC", "DecoupledMPCBatch", "closed_loop_matrices", "closed_loop_poles", "check_closed_loop"]

STABILITY_MARGIN = 1e-3  # default: a pole modulus above 1 - this is refused
_SERIES_BELOW = 0.1  # discretize_axis: phi_2 by its series below this damping x period
_SERIES_TERMS = 14  # terms of that series: the next is below 0.1^14 / 16! < 1e-27


class MPCError(RobotinoError, ValueError):
    """An MPC input or setting with the wrong shape, a non-finite value or out of range."""


class UnstableClosedLoopError(ParamError):
    """Control parameters whose nominal closed loop (eqs. 49 and 56) has a pole on or outside the unit circle."""


def axis_dampings(p: RobotinoParams) -> np.ndarray:
    """Damping rates (k_x/M, k_y/M, k_theta/J) [1/s] of the three axes (blocks of eq. 3)."""
    return np.array([p.k_x / p.M, p.k_y / p.M, p.k_theta / p.J])


def discretize_axis(damping: float, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of one axis, x' = [[0, 1], [0, -damping]] x + [0, 1]^T u.

    Parameters
    ----------
    damping
        k / m [1/s], >= 0.
    period_s
        Sampling period Ts [s], > 0.

    Returns
    -------
    A_d : ndarray, shape (2, 2)
        expm(A Ts), the A_(.)k of eq. (49).
    B_d : ndarray, shape (2,)
        int_0^Ts expm(A s) ds B, the B_(.)k of eq. (49).

    Notes
    -----
    Closed form of the damped double integrator, with a = damping, x = a Ts:
    A_d = [[1, Ts phi_1], [0, e^{-x}]], B_d = [Ts^2 phi_2, Ts phi_1], where
    phi_1 = (1 - e^{-x}) / x and phi_2 = (x - 1 + e^{-x}) / x^2 (the a -> 0
    limits 1 and 1/2 give Ts and Ts^2 / 2 for a = 0). phi_1 uses expm1;
    phi_2 its Taylor series sum_k (-x)^k / (k + 2)! below x = 0.1, where the
    difference would cancel.
    """
    if not (np.isfinite(damping) and damping >= 0.0):
        raise MPCError(f"damping must be finite and >= 0, got {damping!r}")
    if not (np.isfinite(period_s) and period_s > 0.0):
        raise MPCError(f"period_s must be finite and > 0, got {period_s!r}")
    T = float(period_s)
    x = float(damping) * T
    decay = math.exp(-x)
    phi_1 = -math.expm1(-x) / x if x > 0.0 else 1.0
    if x < _SERIES_BELOW:
        phi_2, term = 0.0, 0.5
        for k in range(_SERIES_TERMS):
            phi_2 += term
            term *= -x / (k + 3)
    else:
        phi_2 = (x + math.expm1(-x)) / (x * x)
    return np.array([[1.0, T * phi_1], [0.0, decay]]), np.array([T * T * phi_2, T * phi_1])


def prediction_matrices(A_d: np.ndarray, B_d: np.ndarray, horizon: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prediction matrices of eq. (50), Y = G_p x(k) + F_1p Delta U + F_2p u(k-1), with erratum 3.

    Parameters
    ----------
    A_d, B_d
        Discrete axis model (eq. 49), shapes (n, n) and (n,); the output is H = e_1.
    horizon
        N >= 1.

    Returns
    -------
    G_p : ndarray, shape (N, n)
        Row j (1-based) is H A^j (eq. 52).
    F_1p : ndarray, shape (N, N)
        Lower-triangular Toeplitz, entry (j, l) = S_{j-l+1} for l <= j (0-based),
        with S_m = H (I + A + ... + A^{m-1}) B.
    F_2p : ndarray, shape (N,)
        Entry j (1-based) is S_j (eq. 53 corrected).

    Notes
    -----
    With u(k+m) = u(k-1) + sum_{l<=m} Delta u(k+l) (eq. 48),
    y(k+j) = H A^j x(k) + sum_{m=0}^{j-1} H A^{j-1-m} B u(k+m); collecting
    the coefficients of u(k-1) and of each Delta u(k+l) gives the sums S_m
    (the printed eqs. 52-53 add one I too many per term).
    """
    A_d = np.asarray(A_d, dtype=float)
    B_d = np.asarray(B_d, dtype=float)
    n = A_d.shape[0]
    if A_d.shape != (n, n) or B_d.shape != (n,):
        raise MPCError(f"A_d must be square and B_d a matching vector, got {A_d.shape} and {B_d.shape}")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise MPCError(f"horizon must be an integer >= 1, got {horizon!r}")
    N = int(horizon)
    G_p, S, F_1p = np.empty((N, n)), np.empty(N), np.zeros((N, N))
    power, partial = np.eye(n), np.zeros(n)  # A^(j-1) and (I + ... + A^(j-1)) B
    for j in range(N):
        partial = partial + power @ B_d
        power = power @ A_d
        G_p[j], S[j] = power[0], partial[0]
        F_1p[j, : j + 1] = S[j::-1]
    return G_p, F_1p, S.copy()


class DecoupledMPC:
    """The three per-axis MPCs of Section V, stacked (axes x, y, theta).

    Parameters
    ----------
    robot
        Physical parameters (M, J, k_x, k_y, k_theta): the model of eq. (3).
    control
        Period Ts, horizon N and the per-axis weights Q_p (q_x, q_y, q_theta)
        and R_p (r_x, r_y, r_theta).

    Attributes
    ----------
    A_d, B_d : ndarray, shapes (3, 2, 2), (3, 2)
        Discrete models per axis (eq. 49).
    G_p, F_1p, F_2p : ndarray, shapes (3, N, 2), (3, N, N), (3, N)
        Prediction matrices per axis (eqs. 50-53, erratum 3).
    hessian : ndarray, shape (3, N, N)
        F_1p^T Q_p F_1p + R_p per axis.
    gain : ndarray, shape (3, N, N)
        (F_1p^T Q_p F_1p + R_p)^{-1} F_1p^T Q_p per axis (eq. 56).
    stacked_gain : ndarray, shape (3, 3N + 9)
        Delta u(k) = stacked_gain @ (Y_d.ravel(), X, u(k-1)): the first row of
        the gain folded with G_p and F_2p, for the three axes at once.
    prediction_map : ndarray, shape (3N, 3N + 9)
        Y(k).ravel() = prediction_map @ (Y_d.ravel(), X, u(k-1)): eq. (50) under
        the optimal increments of eq. (56), both linear in that vector.

    Notes
    -----
    The cost is J = 1/2 sum_j q (y_d(k+j) - y(k+j))^2 + 1/2 sum_j r Delta u(k+j-1)^2
    for j = 1..N with Q_p = q I and R_p = r I: the penalty runs over the
    decision vector Delta u(k) .. Delta u(k+N-1) (erratum 5), and both terms
    carry the 1/2 so that the printed closed form (56) is its exact minimiser
    (eq. 54 as printed lacks the 1/2 on the R_p term, which only rescales r).
    """

    def __init__(self, robot: RobotinoParams, control: ControlParams) -> None:
        self.period_s, self.horizon = float(control.period_s), int(control.horizon)
        q, r = np.asarray(control.q, dtype=float), np.asarray(control.r, dtype=float)
        if not (np.all(np.isfinite(q)) and np.all(q > 0) and np.all(np.isfinite(r)) and np.all(r > 0)):
            raise MPCError(f"weights q and r must be finite and > 0, got q={tuple(q)}, r={tuple(r)}")
        self.q, self.r = q, r
        N = self.horizon
        self.A_d, self.B_d, self.G_p = np.empty((3, 2, 2)), np.empty((3, 2)), np.empty((3, N, 2))
        self.F_1p, self.F_2p = np.empty((3, N, N)), np.empty((3, N))
        self.hessian, self.gain = np.empty((3, N, N)), np.empty((3, N, N))
        for a, damping in enumerate(axis_dampings(robot)):
            self.A_d[a], self.B_d[a] = discretize_axis(damping, self.period_s)
            self.G_p[a], self.F_1p[a], self.F_2p[a] = prediction_matrices(self.A_d[a], self.B_d[a], N)
            F1 = self.F_1p[a]
            self.hessian[a] = q[a] * F1.T @ F1 + r[a] * np.eye(N)
            self.gain[a] = np.linalg.solve(self.hessian[a], q[a] * F1.T)
        # Receding horizon: Delta u(k) = K0 (Y_d - G_p x - F_2p u(k-1)), K0 the first row of (56),
        # for all axes as one matrix on z = (Y_d row by row, X = x row by row, u(k-1)).
        k_ref = self.gain[:, 0, :]  # (3, N)
        K = np.zeros((3, 3 * N + 9))
        for a in range(3):
            K[a, a : 3 * N : 3] = k_ref[a]
            K[a, 3 * N + 2 * a : 3 * N + 2 * a + 2] = -k_ref[a] @ self.G_p[a]
            K[a, 3 * N + 6 + a] = -k_ref[a] @ self.F_2p[a]
        self.stacked_gain = K
        # The same gain per axis as Python floats for `delta_u`: the reference row, and
        # (position, velocity, u(k-1)) of the block-diagonal state part.
        self._reference_gains = tuple(tuple(K[a, a : 3 * N : 3].tolist()) for a in range(3))
        self._state_gains = tuple(
            (float(K[a, 3 * N + 2 * a]), float(K[a, 3 * N + 2 * a + 1]), float(K[a, 3 * N + 6 + a])) for a in range(3)
        )
        # Eq. (50) under eq. (56): Y = M Y_d + (I - M)(G_p x + F_2p u(k-1)) per axis, M = F_1p gain
        self.prediction_map = np.zeros((3 * N, 3 * N + 9))
        for a in range(3):
            M = self.F_1p[a] @ self.gain[a]
            self.prediction_map[a::3, a : 3 * N : 3] = M
            self.prediction_map[a::3, 3 * N + 2 * a : 3 * N + 2 * a + 2] = (np.eye(N) - M) @ self.G_p[a]
            self.prediction_map[a::3, 3 * N + 6 + a] = (np.eye(N) - M) @ self.F_2p[a]

    def predict(self, x: np.ndarray, u_prev: np.ndarray, delta_U: np.ndarray) -> np.ndarray:
        """Predicted outputs Y(k) (eq. 50), shape (N, 3).

        Parameters
        ----------
        x
            Per-axis states (pos, vel), shape (3, 2).
        u_prev
            u(k-1) per axis, shape (3,).
        delta_U
            Delta u(k) .. Delta u(k+N-1), shape (N, 3).
        """
        return (
            np.einsum("anm,am->na", self.G_p, x)
            + np.einsum("anl,la->na", self.F_1p, delta_U)
            + self.F_2p.T * u_prev
        )

    def free_error(self, x: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray) -> np.ndarray:
        """Y_d - G_p x(k) - F_2p u(k-1), the bracket of eq. (56), shape (N, 3)."""
        return Y_d - np.einsum("anm,am->na", self.G_p, x) - self.F_2p.T * u_prev

    def solve(self, x: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray) -> np.ndarray:
        """The whole optimal increment sequence of eq. (56), shape (N, 3)."""
        return np.einsum("anm,ma->na", self.gain, self.free_error(x, u_prev, Y_d))

    def predicted(
        self, X: Sequence[float], u_prev: Sequence[float], Y_d: Sequence[Sequence[float]]
    ) -> np.ndarray:
        """`predict` under the increments of `solve` (eq. 50 under eq. 56) from a step's floats, shape (N, 3).

        One product of `prediction_map` (the same numbers up to rounding); the arguments as for `delta_u`.
        """
        return (self.prediction_map @ [*chain.from_iterable(Y_d), *X, *u_prev]).reshape(self.horizon, 3)

    def delta_u(
        self, X: Sequence[float], u_prev: Sequence[float], Y_d: Sequence[Sequence[float]]
    ) -> list[float]:
        """First component Delta u(k) of eq. (56) for the three axes, one run on Python floats (the per-tick path).

        ``stacked_gain @ (Y_d.ravel(), X, u(k-1))`` as sums of products: numpy's per-call overhead on one run
        would cost 2.6 times as much (``bench float_path``); B runs at once: `DecoupledMPCBatch.delta_u`.

        Parameters
        ----------
        X
            Body state (x, x', y, y', theta, theta') of eq. (2), 6 floats.
        u_prev
            u(k-1), 3 floats.
        Y_d
            Reference positions y_d(k+1) .. y_d(k+N), N rows of 3 floats.

        Returns
        -------
        list of 3 floats
            Delta u(k) of eq. (56) for (x, y, theta); unchecked (the controller checks its inputs once).
        """
        px, vx, py, vy, pt, vt = X
        upx, upy, upt = u_prev
        (kyx, kyy, kyt), (yx, yy, yt) = self._reference_gains, zip(*Y_d)
        (kpx, kvx, kux), (kpy, kvy, kuy), (kpt, kvt, kut) = self._state_gains
        return [
            sum(map(mul, kyx, yx)) + kpx * px + kvx * vx + kux * upx,
            sum(map(mul, kyy, yy)) + kpy * py + kvy * vy + kuy * upy,
            sum(map(mul, kyt, yt)) + kpt * pt + kvt * vt + kut * upt,
        ]


class DecoupledMPCBatch:
    """The MPCs of B controller models at once (`DecoupledMPC` per run, stacked): array attributes (B, ...).

    The relations of `DecoupledMPC.__init__` and `prediction_matrices` on the stacked axes (B, 3), equal to each
    run's own to rounding; `delta_u` steps each run by its own gain.

    Parameters
    ----------
    robots
        Each run's controller model (B >= 1).
    control
        Period, horizon and weights, shared by the runs.

    Attributes
    ----------
    A_d, B_d, G_p, F_1p, F_2p, hessian, gain, stacked_gain, prediction_map
        As `DecoupledMPC`'s, with a leading batch axis (B, ...).
    """

    def __init__(self, robots: Sequence[RobotinoParams], control: ControlParams) -> None:
        first = DecoupledMPC(robots[0], control)  # checks the weights (every run's)
        N, B, eye, T = first.horizon, len(robots), np.eye(first.horizon), first.period_s
        self.period_s, self.horizon, self.q, self.r = T, N, np.tile(first.q, (B, 1)), np.tile(first.r, (B, 1))
        models = [discretize_axis(damping, T) for p in robots for damping in axis_dampings(p)]
        self.A_d = np.reshape([a for a, _ in models], (B, 3, 2, 2))
        self.B_d = np.reshape([b for _, b in models], (B, 3, 2))
        self.G_p, self.F_1p, self.F_2p = np.empty((B, 3, N, 2)), np.zeros((B, 3, N, N)), np.empty((B, 3, N))
        power, partial = np.tile(np.eye(2), (B, 3, 1, 1)), np.zeros((B, 3, 2))
        for j in range(N):  # `prediction_matrices`, every axis of every run at once
            partial = partial + np.einsum("...ij,...j->...i", power, self.B_d)
            power = power @ self.A_d
            self.G_p[..., j, :], self.F_2p[..., j] = power[..., 0, :], partial[..., 0]
            self.F_1p[..., j, : j + 1] = self.F_2p[..., j::-1]
        q, r, F1T = first.q[:, None, None], first.r[:, None, None], self.F_1p.swapaxes(-1, -2)
        self.hessian = q * F1T @ self.F_1p + r * eye
        self.gain = np.linalg.solve(self.hessian, q * F1T)
        k, M = self.gain[..., 0, :], self.F_1p @ self.gain  # (B, 3, N), (B, 3, N, N)
        self.stacked_gain, self.prediction_map = np.zeros((B, 3, 3 * N + 9)), np.zeros((B, 3 * N, 3 * N + 9))
        for a in range(3):
            self.stacked_gain[:, a, a : 3 * N : 3] = k[:, a]
            self.stacked_gain[:, a, 3 * N + 2 * a : 3 * N + 2 * a + 2] = -np.einsum("bn,bnm->bm", k[:, a],
                                                                                     self.G_p[:, a])
            self.stacked_gain[:, a, 3 * N + 6 + a] = -np.einsum("bn,bn->b", k[:, a], self.F_2p[:, a])
            self.prediction_map[:, a::3, a : 3 * N : 3] = M[:, a]
            self.prediction_map[:, a::3, 3 * N + 2 * a : 3 * N + 2 * a + 2] = (eye - M[:, a]) @ self.G_p[:, a]
            self.prediction_map[:, a::3, 3 * N + 6 + a] = np.einsum("bij,bj->bi", eye - M[:, a], self.F_2p[:, a])
        # the stacked gain entry by entry, (3, 3N + 9, B): one contiguous row per entry, `delta_u` twice as fast
        self._gain_rows = np.ascontiguousarray(self.stacked_gain.transpose(1, 2, 0))

    def delta_u(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray) -> np.ndarray:
        """`DecoupledMPC.delta_u` of each run by its own gain: X (B, 6), u_prev (B, 3), Y_d (N, 3) shared or
        (B, N, 3) -> (B, 3).
        """
        Y_d, X, n = np.asarray(Y_d, dtype=float), np.asarray(X, dtype=float), 3 * np.shape(Y_d)[-2]
        z = np.empty((n + 9, len(X)))  # (Y_d.ravel(), X, u(k-1)) per run, a column each
        z[:n], z[n : n + 6], z[n + 6 :] = Y_d.reshape(-1, n).T, X.T, np.transpose(u_prev)
        return np.einsum("akb,kb->ba", self._gain_rows, z)


def closed_loop_matrices(mpc: DecoupledMPC) -> np.ndarray:
    """Nominal closed loop of each axis under the receding-horizon law, z(k+1) = Phi_a z(k).

    Parameters
    ----------
    mpc
        The three MPCs (their discrete models, eq. 49, and gains, eq. 56).

    Returns
    -------
    ndarray, shape (3, 3, 3)
        Phi_a for the axes (x, y, theta), on z(k) = (pos(k), vel(k), u(k-1)).

    Notes
    -----
    With the reference at zero, eq. (56)'s first row k_0 gives
    Delta u(k) = -k_0 G_p x(k) - k_0 F_2p u(k-1), so u(k) = (1 - k_0 F_2p) u(k-1) - k_0 G_p x(k)
    and x(k+1) = A_d x(k) + B_d u(k) (eq. 49). The reference enters as an
    input, so the poles decide stability for every trajectory.
    """
    Phi = np.empty((3, 3, 3))
    for a in range(3):
        k0 = mpc.gain[a, 0]
        k_state, k_input = k0 @ mpc.G_p[a], k0 @ mpc.F_2p[a]
        B = mpc.B_d[a]
        Phi[a, :2, :2] = mpc.A_d[a] - np.outer(B, k_state)
        Phi[a, :2, 2] = B * (1.0 - k_input)
        Phi[a, 2, :2] = -k_state
        Phi[a, 2, 2] = 1.0 - k_input
    return Phi


def closed_loop_poles(robot: RobotinoParams, control: ControlParams) -> np.ndarray:
    """Poles of the nominal closed loop of the Delta-u MPC, per axis.

    Parameters
    ----------
    robot
        The controller's model (masses and frictions of eq. 3).
    control
        Period, horizon and weights.

    Returns
    -------
    ndarray of complex, shape (3, 3)
        Row a: the eigenvalues of `closed_loop_matrices` for axis (x, y, theta)[a],
        state (position, velocity, u(k-1)); stable iff all have modulus < 1.

    Raises
    ------
    MPCError
        For weights that are not finite and positive (from `DecoupledMPC`).
    """
    return np.linalg.eigvals(closed_loop_matrices(DecoupledMPC(robot, control)))


def check_closed_loop(
    robot: RobotinoParams, control: ControlParams, margin: float = STABILITY_MARGIN
) -> np.ndarray:
    """Refuse control parameters whose nominal closed loop is not asymptotically stable.

    Parameters
    ----------
    robot, control
        As for `closed_loop_poles`.
    margin
        A spectral radius >= 1 - margin is refused (0 <= margin < 1).

    Returns
    -------
    ndarray, shape (3,)
        The spectral radii of the axes (x, y, theta), all below 1 - margin.

    Raises
    ------
    UnstableClosedLoopError
        Naming each failing axis, its spectral radius, its weights q, r and the horizon and period.
    MPCError
        For a margin out of range or weights that are not finite and positive.
    """
    if not (0.0 <= margin < 1.0):
        raise MPCError(f"margin must be in [0, 1), got {margin!r}")
    radii = np.abs(closed_loop_poles(robot, control)).max(axis=1)
    bad = [
        f"axis {axis}: spectral radius {radius:.6f} (q_{axis} = {q:g}, r_{axis} = {r:g}, q/r = {q / r:.3g})"
        for axis, radius, q, r in zip(AXES, radii, control.q, control.r)
        if not radius < 1.0 - margin
    ]
    if bad:
        raise UnstableClosedLoopError(
            f"control weights give an unstable closed loop (horizon {control.horizon}, period {control.period_s:g} s,"
            f" limit 1 - {margin:g}): " + "; ".join(bad)
        )
    return radii
