"""Order of output functional controllability (Section IV): projection condition (38) and Theorem 1.

Two independent routes give the order, the smallest i such that every output
trajectory with a continuous i-th derivative can be followed:

* `functional_order`: the projection condition (38),
  F subset F cap Z_{i-1} + ker C with Z_0 = im B, Z_j = im B + A (Z_{j-1} cap F cap ker C);
* `markov_order`: the structure at infinity from the Markov parameters
  M_k = C A^k B; the order is the smallest k at which the block lower-triangular
  Toeplitz matrices T_k = [M_{i-j}] (0 <= j <= i < k) gain rank C; when the first
  non-zero Markov parameter M_{k-1} has full row rank (a uniform relative
  degree), that k.

For the Robotino: order 2 for the mechanics (force/acceleration in, position
out), 1 for a DC drive (voltage in, current or force out), 3 for the cascade
(voltages in, positions out), as Theorem 1 states.
"""

from __future__ import annotations

import numpy as np

from robotino_geom_mpc.geometric import subspaces as geo
from robotino_geom_mpc.geometric.decoupling import AXES, B_decoupled, DecouplingField
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.model.dynamics import (A_matrix, C_matrix, N_BODY, OUTPUT_INDEX, VELOCITY_INDEX, drive_matrices,
                                              g_theta, wheel_directions)
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = [
    "FunctionalError",
    "functional_order",
    "markov_order",
    "axis_subspace",
    "cascade_matrices",
    "mechanical_orders",
    "drive_orders",
    "cascade_orders",
    "functional_controllability",
]


class FunctionalError(RobotinoError, ValueError):
    """A system matrix with the wrong shape or non-finite entries, or a bad order bound."""


def _system(A: object, B: object, C: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    arrs = []
    for name, M in (("A", A), ("B", B), ("C", C)):
        arr = np.asarray(M, dtype=float)
        if arr.ndim != 2:
            raise FunctionalError(f"{name} must be a matrix, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise FunctionalError(f"{name} has non-finite entries")
        arrs.append(arr)
    A, B, C = arrs
    n = A.shape[0]
    if A.shape != (n, n):
        raise FunctionalError(f"A must be square, got shape {A.shape}")
    if B.shape[0] != n:
        raise FunctionalError(f"B must have {n} rows, got shape {B.shape}")
    if C.shape[1] != n:
        raise FunctionalError(f"C must have {n} columns, got shape {C.shape}")
    return A, B, C


def _bound(max_order: int | None, n: int) -> int:
    if max_order is None:
        return n + 1
    if isinstance(max_order, bool) or not isinstance(max_order, (int, np.integer)) or max_order < 1:
        raise FunctionalError(f"max_order must be an integer >= 1, got {max_order!r}")
    return int(max_order)


def functional_order(
    A: object, B: object, C: object, F: object | None = None, max_order: int | None = None, rtol: float | None = None
) -> int | None:
    """Order of functional controllability by the projection condition, eq. (38).

    Parameters
    ----------
    A, B, C
        The triple (n x n, n x m, p x n).
    F
        Candidate subspace of states (basis matrix, e.g. F_x of eq. 43); None is R^n.
    max_order
        Largest order tried; default n + 1 (Z_j is constant from j = n on, so a
        condition that fails there fails for every order).
    rtol
        Rank tolerance of the geometric toolbox.

    Returns
    -------
    int or None
        The smallest i >= 1 with F subset (F cap Z_{i-1}) + ker C, None if there is none
        (the output is not functionally controllable on F).
    """
    A, B, C = _system(A, B, C)
    n = A.shape[0]
    bound = _bound(max_order, n)
    Fq = np.eye(n) if F is None else geo.image(F, rtol)
    if Fq.shape[0] != n:
        raise FunctionalError(f"F must have {n} rows, got shape {np.asarray(F).shape}")
    kerC = geo.kernel(C, rtol)
    Z = geo.z_sequence(A, B, kerC, Fq, steps=min(bound - 1, n), rtol=rtol)
    for i, Z_prev in enumerate(Z, start=1):  # condition (38) for order i uses Z_{i-1}
        if geo.is_subspace(Fq, geo.subspace_sum(geo.intersection(Fq, Z_prev, rtol=rtol), kerC, rtol=rtol), rtol):
            return i
    return None


def markov_order(A: object, B: object, C: object, max_order: int | None = None,
                 rtol: float | None = None) -> int | None:
    """Order of functional controllability from the Markov parameters C A^k B (structure at infinity).

    Parameters
    ----------
    A, B, C
        The triple (n x n, n x m, p x n).
    max_order
        Largest order tried; default n + 1.
    rtol
        Rank tolerance: singular values of T_k up to ``rtol * max(sigma_max, 1)``
        count as zero (the scaled Markov parameters are at most one); default
        ``geometry.default_rtol`` of T_k's shape.

    Returns
    -------
    int or None
        The smallest k with rank T_k - rank T_{k-1} = rank C, where T_k is the
        k x k block lower-triangular Toeplitz matrix of M_0 ... M_{k-1}; None if
        the output is not functionally controllable (not right invertible).

    Notes
    -----
    rank T_k - rank T_{k-1} is the number of zeros at infinity of order <= k;
    it reaches rank C exactly when outputs with continuous k-th derivatives can
    be reproduced. Time scaling (A, B) -> (A, B) / ||A|| and the norms of B and
    C scale the Markov parameters to at most one without changing any rank.
    """
    A, B, C = _system(A, B, C)
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    bound = _bound(max_order, n)
    a = np.linalg.norm(A, 2) or 1.0
    An = A / a
    Bn = B / (a * (np.linalg.norm(B, 2) or 1.0))
    Cn = C / (np.linalg.norm(C, 2) or 1.0)
    target = np.linalg.matrix_rank(Cn)
    if target == 0:
        return 1
    markov = [Cn @ Bn]
    previous = 0
    for k in range(1, bound + 1):
        if len(markov) < k:
            markov.append(Cn @ np.linalg.matrix_power(An, k - 1) @ Bn)
        T = np.zeros((k * p, k * m))
        for i in range(k):
            for j in range(i + 1):
                T[i * p : (i + 1) * p, j * m : (j + 1) * m] = markov[i - j]
        s = np.linalg.svd(T, compute_uv=False)
        tol = geo.default_rtol(*T.shape) if rtol is None else rtol
        rank = int(np.sum(s > tol * max(s[0], 1.0)))
        if rank - previous == target:
            return k
        previous = rank
    return None


def axis_subspace(axis: str) -> np.ndarray:
    """F_x, F_y or F_theta of eqs. (43)-(44): position and velocity of one axis (6 x 2)."""
    if axis not in AXES:
        raise FunctionalError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")
    j = AXES.index(axis)
    F = np.zeros((N_BODY, 2))
    F[OUTPUT_INDEX[j], 0] = F[VELOCITY_INDEX[j], 1] = 1.0
    return F


def cascade_matrices(theta: float, p: RobotinoParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body plus three armature currents at a frozen heading theta: voltages in, (x, y, theta) out.

    State (x, x', y, y', theta, theta', i_1, i_2, i_3):
    X' = A X + g(theta) k_F i with k_F = gear Km / r, and
    L i' = U - R i - Km (gear / r) W(theta) X, W(theta) X the wheel rim speeds.
    This is the linearisation of `model.coupled_rhs` at rest with zero
    currents (the derivatives with respect to theta vanish there).

    Returns
    -------
    A_c (9, 9), B_c (9, 3), C_c (3, 9)
    """
    th = float(theta)
    if not np.isfinite(th):
        raise FunctionalError("theta must be finite")
    k_F = p.gear_ratio * p.torque_constant_n_m_per_a / p.r
    W = np.zeros((3, N_BODY))
    W[:, VELOCITY_INDEX] = np.column_stack((wheel_directions(th), np.full(3, p.l)))
    L = p.inductance_h
    A_c = np.zeros((N_BODY + 3, N_BODY + 3))
    A_c[:N_BODY, :N_BODY] = A_matrix(p)
    A_c[:N_BODY, N_BODY:] = g_theta(th, p) * k_F
    A_c[N_BODY:, :N_BODY] = -p.torque_constant_n_m_per_a * p.gear_ratio / p.r * W / L
    A_c[N_BODY:, N_BODY:] = -p.resistance_ohm / L * np.eye(3)
    B_c = np.vstack((np.zeros((N_BODY, 3)), np.eye(3) / L))
    C_c = np.hstack((C_matrix(), np.zeros((3, 3))))
    return A_c, B_c, C_c


def _both(A: np.ndarray, B: np.ndarray, C: np.ndarray, F: np.ndarray | None = None) -> dict[str, int | None]:
    return {"projection": functional_order(A, B, C, F), "markov": markov_order(A, B, C)}


def mechanical_orders(p: RobotinoParams, theta: float = 0.0) -> dict[str, dict[str, int | None]]:
    """Orders of the mechanics: B of eq. (37) per axis on F_x, F_y, F_theta (eqs. 43-44), the whole, and g(theta)."""
    A, B, C = A_matrix(p), B_decoupled(), C_matrix()
    out = {}
    for j, a in enumerate(AXES):
        o = _both(A, B, C[j : j + 1], axis_subspace(a))
        # the Markov route has no F: it uses the axis' own input column
        o["markov"] = markov_order(A, B[:, j : j + 1], C[j : j + 1])
        out[a] = o
    out["whole (B of eq. 37)"] = _both(A, B, C)
    out["whole (g(theta))"] = _both(A, g_theta(theta, p), C)
    return out


def drive_orders(p: RobotinoParams) -> dict[str, dict[str, int | None]]:
    """Orders of the three DC drives of eq. (10): voltage in; current (= force / k_F) or speed out."""
    A, B = drive_matrices(p)
    current = np.zeros((3, 6))
    current[np.arange(3), [0, 2, 4]] = 1.0
    k_F = p.gear_ratio * p.torque_constant_n_m_per_a / p.r
    speed = np.zeros((3, 6))
    speed[np.arange(3), [1, 3, 5]] = 1.0
    return {
        "current": _both(A, B, current),
        "force": _both(A, B, k_F * current),
        "motor speed": _both(A, B, speed),
    }


def cascade_orders(p: RobotinoParams, thetas: tuple[float, ...] = (0.0, np.pi / 4, np.pi / 2, np.pi)) -> dict:
    """Orders of the cascade (Theorem 1) at each heading, whole and per axis with the decoupled input.

    The decoupled input w enters as U = (L / k_F) T(theta) w, so that the third
    Markov parameter C A_c^2 B_c is the identity and axis j has input column j.
    """
    field = DecouplingField(p)
    k_F = p.gear_ratio * p.torque_constant_n_m_per_a / p.r
    out = {}
    for th in thetas:
        A_c, B_c, C_c = cascade_matrices(th, p)
        B_w = B_c @ (p.inductance_h / k_F * field.field(th))
        entry = {"whole": _both(A_c, B_c, C_c)}
        for j, a in enumerate(AXES):
            entry[a] = _both(A_c, B_w[:, j : j + 1], C_c[j : j + 1])
        out[f"{th:.6g}"] = entry
    return out


def _agreed(results: list[dict[str, int | None]]) -> int | None:
    values = {v for r in results for v in r.values()}
    return values.pop() if len(values) == 1 else None


def functional_controllability(p: RobotinoParams) -> dict:
    """Summary of Section IV: {"mechanical": 2, "drive": 1, "cascade": 3} when both routes agree everywhere.

    The drive's order is that of its output into the mechanics, the current
    (equivalently the wheel force); the motor speed (order 2) is listed in the
    details only. A value is None when the routes or the cases disagree;
    ``details`` holds every case.
    """
    mech, drive, casc = mechanical_orders(p), drive_orders(p), cascade_orders(p)
    cascade_cases = [case for entry in casc.values() for case in entry.values()]
    return {
        "orders": {
            "mechanical": _agreed(list(mech.values())),
            "drive": _agreed([drive["current"], drive["force"]]),
            "cascade": _agreed(cascade_cases),
        },
        "details": {"mechanical": mech, "drive": drive, "cascade": casc},
    }
