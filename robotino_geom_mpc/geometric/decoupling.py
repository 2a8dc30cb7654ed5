"""The decoupling field T(theta) of Section III (eqs. 33-37) and a check of conditions (12)-(21).

`decoupling_field_toolbox` builds T_x, T_y, T_theta with the geometric toolbox;
`DecouplingField` is the fast path of the control loop, T(theta) =
T(0) diag(R(theta)^T, 1) with T(0) = G3(0)^{-1} (eq. 37); `check_decoupling`
verifies both on a theta grid that contains the points pi/2 + k pi where the
paper places singularities (erratum 2: there are none).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from robotino_geom_mpc.geometric import subspaces as geo
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.model.dynamics import A_matrix, C_matrix, VELOCITY_INDEX, g_theta, wheel_directions
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = [
    "AXES",
    "DecouplingError",
    "B_decoupled",
    "g_theta_stack",
    "decoupling_field_toolbox",
    "DecouplingField",
    "DecouplingFieldBatch",
    "ConditionResult",
    "DecouplingReport",
    "theta_grid",
    "check_decoupling",
    "subspace_dimensions",
]

AXES = ("x", "y", "theta")


class DecouplingError(RobotinoError, ValueError):
    """A non-finite or mis-shaped theta, or a grid size out of range."""


def _thetas(theta: object) -> np.ndarray:
    arr = np.asarray(theta, dtype=float)
    if arr.ndim > 1:
        raise DecouplingError(f"theta must be a scalar or a 1-d array, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise DecouplingError("theta must be finite")
    return arr


def B_decoupled() -> np.ndarray:
    """B of eq. (37): unit accelerations x'', y'', theta'' (6 x 3)."""
    B = np.zeros((6, 3))
    B[VELOCITY_INDEX, np.arange(3)] = 1.0
    return B


def g_theta_stack(theta: object, p: RobotinoParams) -> np.ndarray:
    """g(theta) of eq. (9) for a scalar (6, 3) or a 1-d array of angles (n, 6, 3)."""
    th = _thetas(theta)
    if th.ndim == 0:
        return g_theta(float(th), p)
    return np.stack([g_theta(float(t), p) for t in th]) if th.size else np.zeros((0, 6, 3))


def _axis_subspaces(g: np.ndarray, p: RobotinoParams, rtol: float | None) -> list[np.ndarray]:
    """For each axis j, im g cap V*_j with V*_j = maxV(A, im g, cap_{k != j} ker C_k)."""
    A, C = A_matrix(p), C_matrix()
    img = geo.image(g, rtol)
    out = []
    for j in range(3):
        others = geo.kernel(np.delete(C, j, axis=0), rtol)
        out.append(geo.intersection(img, geo.maxV(A, img, others, rtol), rtol=rtol))
    return out


def decoupling_field_toolbox(theta: object, p: RobotinoParams, rtol: float | None = None) -> np.ndarray:
    """T(theta) = [T_x, T_y, T_theta] by eqs. (33)-(36), with the geometric toolbox.

    Parameters
    ----------
    theta
        Heading [rad], scalar or 1-d array.
    p
        Robot parameters.
    rtol
        Rank tolerance of the toolbox (see `geometry`).

    Returns
    -------
    numpy.ndarray
        (3, 3), or (n, 3, 3) for n angles; g(theta) T(theta) = B of eq. (37).

    Notes
    -----
    Eq. (33): T_theta = g(theta)^+ w_theta with w_theta a basis of
    im g(theta) cap C_x cap C_y. Read literally (C_x = ker C_x) the
    intersection is im g itself, because g acts on velocities only and
    im g subset ker C; the subspace meant is the part of C_x cap C_y the state
    can stay in, the largest (A, im g)-controlled invariant
    V*_theta = maxV(A, im g, C_x cap C_y) (here the theta block, span(e_5, e_6)),
    whose intersection with im g is one-dimensional. Likewise for x (34) and
    y (35). Each column is then scaled so that its acceleration is one,
    C_j A g T_j = 1, so that g T = B of eq. (37) (eq. 36 stacks the columns).
    """
    return _toolbox_from_g(g_theta_stack(theta, p), p, rtol)


def _toolbox_from_g(g: np.ndarray, p: RobotinoParams, rtol: float | None) -> np.ndarray:
    A, C = A_matrix(p), C_matrix()
    g_pinv = np.linalg.pinv(g)
    columns = []
    for j, w in enumerate(_axis_subspaces(g, p, rtol)):
        if geo.dim(w) != 1:
            raise geo.GeometryError(f"im g cap V*_{AXES[j]} has dimension {geo.dim(w)}, expected 1")
        t = g_pinv @ w
        scale = (C[j] @ A) @ (g @ t)  # acceleration of axis j per unit of t, (..., 1)
        columns.append(t[..., 0] / scale)
    return np.stack(columns, axis=-1)


def _acceleration_blocks_of_full_rank(robots: Sequence[RobotinoParams], rtol: float = 1e-9) -> np.ndarray:
    """G3(0) of each robot, (B, 3, 3) (eq. 9's acceleration rows at theta = 0, `model.dynamics.acceleration_block`), or
    DecouplingError when an im g(0) has numerically a dimension below 3 (relative to its largest entry):
    T(theta) cannot be built on such a model (e.g. a wheel distance of 1e-12 m), as the toolbox's
    construction finds (`decoupling_field_toolbox`).
    """
    d = wheel_directions(0.0)
    mass = np.array([p.M for p in robots])[:, None]
    G3 = np.stack((d[:, 0] / mass, d[:, 1] / mass, np.repeat([[p.l / p.J] for p in robots], 3, axis=1)), axis=1)
    ranks = np.linalg.matrix_rank(G3 / np.abs(G3).max(axis=(1, 2))[:, None, None], tol=rtol)
    if np.any(ranks < 3):
        raise DecouplingError(f"im g(0) has dimension {int(ranks.min())}, expected 3: T(theta) cannot be built on "
                              "this model")
    return G3


class DecouplingField:
    """Fast T(theta) for the control loop: T(theta) = T(0) diag(R(theta)^T, 1).

    Parameters
    ----------
    p
        Robot parameters; T(0) = G3(0)^{-1} is computed once (eq. 37 at theta = 0, the closed form of
        eqs. 33-36; `decoupling_field_toolbox` builds the same columns with the geometric toolbox, and
        `check_decoupling` compares the two).

    Notes
    -----
    The wheel directions satisfy d_i(theta) = (sin(phi_i - theta), cos(phi_i - theta))
    = R(theta) d_i(0) with R the planar rotation (REP-103, erratum 6), and the
    torque row l/J is constant (erratum 1), so the acceleration block of g is
    G3(theta) = diag(R(theta), 1) G3(0). Since G3(theta) T(theta) = I,
    T(theta) = G3(theta)^{-1} = G3(0)^{-1} diag(R(theta), 1)^{-1}
    = T(0) diag(R(theta)^T, 1), defined for every theta: the odom-frame
    accelerations u are turned into the body frame, then distributed.
    """

    def __init__(self, p: RobotinoParams) -> None:
        self.p = p
        self.T0 = np.linalg.inv(_acceleration_blocks_of_full_rank([p])[0])
        self._T0_rows = tuple(map(tuple, self.T0.tolist()))

    def field(self, theta: object) -> np.ndarray:
        """T(theta), (3, 3) for a scalar or (n, 3, 3) for a 1-d array; wheel forces F = T(theta) u."""
        th = _thetas(theta)
        c, s = np.cos(th), np.sin(th)
        rot = np.zeros(th.shape + (3, 3))
        rot[..., 0, 0], rot[..., 0, 1], rot[..., 1, 0], rot[..., 1, 1] = c, s, -s, c
        rot[..., 2, 2] = 1.0
        return self.T0 @ rot

    def forces(self, theta: float, u: Sequence[float]) -> list[float]:
        """Wheel forces F = T(theta) u [N] (eqs. 36-37) of one run on Python floats (the per-tick path).

        T(0) (R(theta)^T (u_x, u_y), u_theta) as sums of products: numpy on one run would cost 20 times as much
        (``bench float_path``); B runs at once: `DecouplingFieldBatch.forces`.

        Parameters
        ----------
        theta
            Heading [rad] (finite; unchecked).
        u
            Accelerations (u_x, u_y, u_theta) the three decoupled axes ask for.
        """
        ux, uy, ut = u
        c, s = math.cos(theta), math.sin(theta)
        rx, ry = c * ux + s * uy, c * uy - s * ux
        (a0, b0, e0), (a1, b1, e1), (a2, b2, e2) = self._T0_rows
        return [a0 * rx + b0 * ry + e0 * ut, a1 * rx + b1 * ry + e1 * ut, a2 * rx + b2 * ry + e2 * ut]


class DecouplingFieldBatch:
    """The fields of B robots at once (`DecouplingField` per run): T(0) of shape (B, 3, 3).

    Parameters
    ----------
    robots
        Each run's robot parameters (B >= 1).
    """

    def __init__(self, robots: Sequence[RobotinoParams]) -> None:
        self.T0 = np.linalg.inv(_acceleration_blocks_of_full_rank(robots))
        self._T0_entries = np.ascontiguousarray(self.T0.transpose(1, 2, 0))  # (3, 3, B): twice as fast as rows

    def forces(self, theta: np.ndarray, u: np.ndarray) -> np.ndarray:
        """`DecouplingField.forces` of each run by its own T(0): theta (B,), u (B, 3) -> (B, 3)."""
        th = _thetas(theta)
        u = np.asarray(u, dtype=float)
        c, s = np.cos(th), np.sin(th)
        ux, uy = u[..., 0], u[..., 1]
        turned = np.empty((3, *np.shape(c)))  # R(theta)^T (u_x, u_y), u_theta: one contiguous row each
        np.add(c * ux, s * uy, out=turned[0, ...])
        np.subtract(c * uy, s * ux, out=turned[1, ...])
        turned[2, ...] = u[..., 2]
        return np.einsum("ijb,jb->bi", self._T0_entries, turned)


@dataclass(frozen=True)
class ConditionResult:
    """One checked condition over the theta grid.

    `value` is the worst residual (must be <= tol) or, for margins, the
    smallest margin (must be > tol).
    """

    equation: str
    axis: str
    statement: str
    measure: str
    value: float
    passed: bool


@dataclass
class DecouplingReport:
    """Result of `check_decoupling`."""

    theta_grid_points: int
    singular_points_included: bool
    max_residual: float
    worst_theta: float
    fast_vs_toolbox_rel: float
    tol: float
    conditions: list[ConditionResult] = field(default_factory=list)
    dimensions: dict[str, int] = field(default_factory=dict)  # at 9 angles over [-pi, pi] (incl. +-pi/2)

    @property
    def passed(self) -> bool:
        return (
            self.max_residual <= self.tol
            and self.fast_vs_toolbox_rel <= self.tol
            and all(c.passed for c in self.conditions)
        )


def theta_grid(n_theta: int = 3600) -> np.ndarray:
    """`n_theta` equally spaced angles over [-pi, pi] plus the points pi/2 + k pi, sorted."""
    if isinstance(n_theta, bool) or not isinstance(n_theta, (int, np.integer)) or n_theta < 2:
        raise DecouplingError(f"n_theta must be an integer >= 2, got {n_theta!r}")
    return np.union1d(np.linspace(-np.pi, np.pi, int(n_theta)), [-np.pi / 2.0, np.pi / 2.0])


def subspace_dimensions(p: RobotinoParams, theta: object = 0.0, rtol: float | None = None) -> dict[str, int]:
    """Dimensions of the subspaces of Section III at `theta` (uniform over a 1-d array of angles)."""
    g = g_theta_stack(theta, p)
    A, C = A_matrix(p), C_matrix()
    img = geo.image(g, rtol)
    ker = {a: geo.kernel(C[j : j + 1], rtol) for j, a in enumerate(AXES)}
    T = decoupling_field_toolbox(theta, p, rtol)
    dims = {
        "im g": geo.dim(img),
        "C_x cap C_y": geo.dim(geo.intersection(ker["x"], ker["y"], rtol=rtol)),
        "im g cap C_x cap C_y (eq. 33 literally)": geo.dim(geo.intersection(img, ker["x"], ker["y"], rtol=rtol)),
    }
    for j, a in enumerate(AXES):
        others = [b for b in AXES if b != a]
        V = geo.maxV(A, img, geo.intersection(ker[others[0]], ker[others[1]], rtol=rtol), rtol)
        dims[f"V*_{a} = maxV(A, im g, C_{others[0]} cap C_{others[1]})"] = geo.dim(V)
        dims[f"im g cap V*_{a}"] = geo.dim(geo.intersection(img, V, rtol=rtol))
        dims[f"R_{a} = minI(A, im g T_{a})"] = geo.dim(geo.minI(A, g @ T[..., j : j + 1], rtol))
    dims["minI(A, im g)"] = geo.dim(geo.minI(A, img, rtol))
    dims["maxV(A, im g, ker C)"] = geo.dim(geo.maxV(A, img, geo.kernel(C, rtol), rtol))
    dims["S* = minS(A, ker C, im g)"] = geo.dim(geo.minS(A, geo.kernel(C, rtol), img, rtol))
    return dims


def check_decoupling(p: RobotinoParams, n_theta: int = 3600, tol: float = 1e-9) -> DecouplingReport:
    """Check T(theta) and conditions (12)-(21) (with D = 0) on a grid over [-pi, pi].

    Parameters
    ----------
    p
        Robot parameters.
    n_theta
        Equally spaced grid points; pi/2 + k pi are added (erratum 2).
    tol
        Pass threshold of every residual (and lower bound of every margin).

    Returns
    -------
    DecouplingReport
        ``max_residual`` = max over the grid of max |g(theta) T(theta) - B| with
        T from the fast path (`DecouplingField`) and B of eq. (37);
        ``fast_vs_toolbox_rel`` = max |T_fast - T_toolbox| / max |T|;
        conditions per axis j (with the other two axes k, l):
        (12/14/16) R_j = minI(A, im g T_j) subset C_k cap C_l, residual
        ||(I - P) Q_R||_2 (sine of the largest principal angle);
        (13/15/17) C_j R_j = im C_j, margin sigma_min(C_j Q_R);
        (18) im(g T_j) = im g cap R_j, largest principal-angle sine both ways;
        (19-21) A R_j subset R_j, residual ||(I - P_R) A Q_R||_2 / ||A||_2.
    """
    thetas = theta_grid(n_theta)
    A, C = A_matrix(p), C_matrix()
    g = g_theta_stack(thetas, p)
    T = DecouplingField(p).field(thetas)
    T_tool = _toolbox_from_g(g, p, None)
    err = np.max(np.abs(g @ T - B_decoupled()), axis=(-2, -1))
    worst = int(np.argmax(err))
    img = geo.image(g)
    An = A / np.linalg.norm(A, 2)
    conditions = []
    eq_in, eq_out, eq_inv = ("12", "14", "16"), ("13", "15", "17"), ("19", "20", "21")
    for j, a in enumerate(AXES):
        others = [b for b in AXES if b != a]
        E = geo.kernel(np.delete(C, j, axis=0))
        gT = g @ T[..., j : j + 1]
        R = geo.minI(A, gT)
        res_in = float(np.max(geo.inclusion_residual(R, E)))
        conditions.append(
            ConditionResult(
                f"({eq_in[j]})", a, f"R_{a} subset C_{others[0]} cap C_{others[1]}",
                "max sine of principal angle", res_in, res_in <= tol,
            )
        )
        sv = np.linalg.svd(C[j : j + 1] @ R, compute_uv=False)[..., 0]
        margin = float(np.min(sv))
        conditions.append(
            ConditionResult(f"({eq_out[j]})", a, f"C_{a} R_{a} = im C_{a}", "min sigma(C_j Q_R)", margin, margin > tol)
        )
        Qv, I = geo.image(gT), geo.intersection(img, R)
        res_eq = float(max(np.max(geo.inclusion_residual(Qv, I)), np.max(geo.inclusion_residual(I, Qv))))
        conditions.append(
            ConditionResult(
                "(18)", a, f"im(g T_{a}) = im g cap R_{a}", "max sine of principal angle", res_eq,
                res_eq <= tol and geo.dim(Qv) == geo.dim(I),
            )
        )
        res_inv = float(np.max(geo.inclusion_residual(An @ R, R)))
        conditions.append(
            ConditionResult(f"({eq_inv[j]})", a, f"A R_{a} subset R_{a}", "||(I-P_R) A Q_R|| / ||A||", res_inv,
                            res_inv <= tol)
        )
    return DecouplingReport(
        theta_grid_points=int(thetas.size),
        singular_points_included=bool(np.all(np.isin([-np.pi / 2.0, np.pi / 2.0], thetas))),
        max_residual=float(err[worst]),
        worst_theta=float(thetas[worst]),
        fast_vs_toolbox_rel=float(np.max(np.abs(T - T_tool)) / np.max(np.abs(T))),
        tol=tol,
        conditions=conditions,
        dimensions=subspace_dimensions(p, np.linspace(-np.pi, np.pi, 9)),
    )
