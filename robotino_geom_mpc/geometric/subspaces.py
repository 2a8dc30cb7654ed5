"""Geometric toolbox of Basile and Marro: subspaces, minI, maxV, S* and the Z_j sequence of eq. (38).

A subspace of R^n is an orthonormal basis matrix of shape (n, k) (k = 0 for the
zero subspace). Every function also accepts a stack of matrices (..., n, k) and
works element by element; the elements of a stack must then have the same
dimension (otherwise `GeometryError`), which is what a theta grid over a
structurally constant system gives.

Numerical rank
--------------
Subspaces come from singular value decompositions. A singular value counts as
zero when it is at most ``max(atol, rtol * sigma_max)``; the default
``rtol = DEFAULT_RTOL_FACTOR * max(m, n) * eps`` (eps the machine epsilon,
m x n the matrix) leaves a margin of three decades above rounding. Every
function takes ``rtol`` to override it per call. Algorithms that apply a map A
work with ``A / ||A||_2`` (same invariant subspaces), so that the tolerance is
relative to the unit scale of the orthonormal bases they combine with.

Reference: G. Basile, G. Marro, *Controlled and Conditioned Invariants in
Linear System Theory*, Prentice Hall, 1992.
"""

from __future__ import annotations

import numpy as np

from robotino_geom_mpc.errors import RobotinoError

__all__ = [
    "DEFAULT_RTOL_FACTOR",
    "GeometryError",
    "default_rtol",
    "dim",
    "image",
    "kernel",
    "orthogonal_complement",
    "subspace_sum",
    "intersection",
    "inverse_image",
    "apply_map",
    "minI",
    "maxV",
    "minS",
    "z_sequence",
    "inclusion_residual",
    "is_subspace",
    "subspaces_equal",
]

DEFAULT_RTOL_FACTOR = 1.0e3
_EPS = np.finfo(float).eps


class GeometryError(RobotinoError, ValueError):
    """A matrix argument with the wrong shape or non-finite entries, or a stack of unequal dimensions."""


def default_rtol(m: int, n: int) -> float:
    """Default relative rank tolerance for an m x n matrix: ``1e3 * max(m, n) * eps``."""
    return DEFAULT_RTOL_FACTOR * max(m, n, 1) * _EPS


def _matrix(M: object, name: str) -> np.ndarray:
    arr = np.asarray(M, dtype=float)
    if arr.ndim < 2:
        raise GeometryError(f"{name} must be a matrix (..., rows, columns), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise GeometryError(f"{name} has non-finite entries")
    return arr


def _square(A: object, name: str = "A") -> np.ndarray:
    arr = _matrix(A, name)
    if arr.shape[-1] != arr.shape[-2]:
        raise GeometryError(f"{name} must be square, got shape {arr.shape}")
    return arr


def _rows(M: np.ndarray, n: int, name: str) -> None:
    if M.shape[-2] != n:
        raise GeometryError(f"{name} must have {n} rows, got shape {M.shape}")


def _concat(*Ms: np.ndarray) -> np.ndarray:
    """Column concatenation with broadcasting of the stack dimensions."""
    if all(M.ndim == 2 for M in Ms):
        return np.concatenate(Ms, axis=-1)
    batch = np.broadcast_shapes(*(M.shape[:-2] for M in Ms))
    return np.concatenate([np.broadcast_to(M, batch + M.shape[-2:]) for M in Ms], axis=-1)


def _uniform(ranks: np.ndarray, what: str) -> int:
    ranks = np.atleast_1d(ranks)
    if ranks.size == 0:
        return 0
    if np.any(ranks != ranks.flat[0]):
        raise GeometryError(f"{what}: dimension varies across the stack ({ranks.min()} to {ranks.max()})")
    return int(ranks.flat[0])


def _rank(s: np.ndarray, shape: tuple[int, int], rtol: float | None, atol: float, what: str) -> int:
    """The numerical rank from singular values s (..., k), uniform over a stack (else GeometryError)."""
    rtol = default_rtol(*shape) if rtol is None else rtol
    if s.ndim == 1:  # a single matrix: the same comparisons on Python floats
        values = s.tolist()
        tol = max(atol, rtol * values[0]) if values else 0.0
        return sum(v > tol for v in values)
    if s.shape[-1] == 0:
        return _uniform(np.zeros(s.shape[:-1], dtype=int), what)
    tol = np.maximum(atol, rtol * s[..., :1])
    return _uniform(np.sum(s > tol, axis=-1), what)


def _norm_map(A: np.ndarray) -> np.ndarray:
    """A / ||A||_2 element-wise over a stack (zero maps stay zero)."""
    norm = np.linalg.norm(A, ord=2, axis=(-2, -1), keepdims=True)
    return A / np.where(norm > 0.0, norm, 1.0)


# The private functions below take checked float arrays (`_matrix`) and, where named Q, orthonormal
# bases: the algorithms call them on their own intermediate results without checking those again.


def _image(M: np.ndarray, rtol: float | None, atol: float) -> np.ndarray:
    U, s, _ = np.linalg.svd(M, full_matrices=False)
    return U[..., : _rank(s, M.shape[-2:], rtol, atol, "image")]


def _kernel(M: np.ndarray, rtol: float | None, atol: float) -> np.ndarray:
    _, s, Vh = np.linalg.svd(M, full_matrices=True)
    return np.swapaxes(Vh[..., _rank(s, M.shape[-2:], rtol, atol, "kernel") :, :], -1, -2)


def _complement(Q: np.ndarray) -> np.ndarray:
    """(im Q)^perp: the trailing columns of a complete QR of Q."""
    n, k = Q.shape[-2:]
    if k == 0:
        return np.broadcast_to(np.eye(n), Q.shape[:-2] + (n, n)).copy()
    return np.linalg.qr(Q, mode="complete")[0][..., k:]


def _intersect(Q: np.ndarray, Qw: np.ndarray, rtol: float | None) -> np.ndarray:
    """im Q cap im Qw (see `intersection`)."""
    k = Q.shape[-1]
    if k == 0 or Qw.shape[-1] == 0:
        batch = np.broadcast_shapes(Q.shape[:-2], Qw.shape[:-2])
        return np.zeros(batch + (Q.shape[-2], 0))
    N = _kernel(_concat(Q, -Qw), rtol, 0.0)
    if N.shape[-1] == 0:
        return np.zeros(N.shape[:-2] + (Q.shape[-2], 0))
    return np.linalg.qr(Q @ N[..., :k, :])[0]


def _inverse_image(An: np.ndarray, Q: np.ndarray, rtol: float) -> np.ndarray:
    """A^{-1} im Q for An = A / ||A||_2 (see `inverse_image`)."""
    return _kernel(np.swapaxes(_complement(Q), -1, -2) @ An, rtol, rtol)


def dim(V: np.ndarray) -> int:
    """Dimension of a subspace given by a basis matrix (its number of columns)."""
    return int(np.shape(V)[-1])


def image(M: object, rtol: float | None = None, atol: float = 0.0) -> np.ndarray:
    """Orthonormal basis of im M (left singular vectors of the non-zero singular values).

    Parameters
    ----------
    M
        Matrix (..., n, k).
    rtol, atol
        Singular values ``<= max(atol, rtol * sigma_max)`` count as zero; `rtol`
        defaults to `default_rtol`.

    Returns
    -------
    numpy.ndarray
        (..., n, r), r = rank M.
    """
    return _image(_matrix(M, "M"), rtol, atol)


def kernel(M: object, rtol: float | None = None, atol: float = 0.0) -> np.ndarray:
    """Orthonormal basis of ker M (right singular vectors of the zero singular values), (..., k, k - r)."""
    return _kernel(_matrix(M, "M"), rtol, atol)


def _is_orthonormal(V: np.ndarray) -> bool:
    k = V.shape[-1]
    if k == 0:
        return True
    gram = np.swapaxes(V, -1, -2) @ V
    return bool(np.max(np.abs(gram - np.eye(k))) <= default_rtol(*V.shape[-2:]))


def _basis(V: np.ndarray, rtol: float | None) -> np.ndarray:
    """V itself when its columns are orthonormal, else an orthonormal basis of im V."""
    return V if _is_orthonormal(V) else _image(V, rtol, 0.0)


def orthogonal_complement(V: object, rtol: float | None = None) -> np.ndarray:
    """Orthonormal basis of (im V)^perp (the trailing columns of a complete QR of a basis of im V)."""
    return _complement(_basis(_matrix(V, "V"), rtol))


def subspace_sum(*Vs: object, rtol: float | None = None) -> np.ndarray:
    """Orthonormal basis of im V_1 + ... + im V_q."""
    if not Vs:
        raise GeometryError("subspace_sum needs at least one subspace")
    mats = [_matrix(V, f"Vs[{k}]") for k, V in enumerate(Vs)]
    for k, V in enumerate(mats[1:], 1):
        _rows(V, mats[0].shape[-2], f"Vs[{k}]")
    return _image(_concat(*mats), rtol, 0.0)


def intersection(*Vs: object, rtol: float | None = None) -> np.ndarray:
    """Orthonormal basis of im V_1 cap ... cap im V_q.

    Notes
    -----
    For orthonormal bases Q_V, Q_W, the kernel of [Q_V, -Q_W] holds the pairs
    (a, b) with Q_V a = Q_W b; its singular values are sqrt(1 - cos phi_i) over
    the principal angles phi_i, so the rank tolerance bounds the angle between
    directions taken as common. The basis Q_V a is orthonormalised by QR.
    """
    if not Vs:
        raise GeometryError("intersection needs at least one subspace")
    mats = [_matrix(V, f"Vs[{k}]") for k, V in enumerate(Vs)]
    for k, V in enumerate(mats[1:], 1):
        _rows(V, mats[0].shape[-2], f"Vs[{k}]")
    Q = _basis(mats[0], rtol)
    for W in mats[1:]:
        Q = _intersect(Q, _basis(W, rtol), rtol)
        if Q.shape[-1] == 0:
            return Q
    return Q


def apply_map(A: object, V: object, rtol: float | None = None) -> np.ndarray:
    """Orthonormal basis of A im V, rank decided relative to ||A||_2 (a map that annihilates V gives 0)."""
    A = _square(A)
    V = _matrix(V, "V")
    _rows(V, A.shape[-1], "V")
    Q = _basis(V, rtol)
    n = A.shape[-1]
    rtol = default_rtol(n, n) if rtol is None else rtol
    return _image(_norm_map(A) @ Q, rtol, rtol)


def inverse_image(A: object, V: object, rtol: float | None = None) -> np.ndarray:
    """Orthonormal basis of A^{-1} im V = {x : A x in im V} = ker((V^perp)^T A)."""
    A = _square(A)
    V = _matrix(V, "V")
    _rows(V, A.shape[-1], "V")
    n = A.shape[-1]
    rtol = default_rtol(n, n) if rtol is None else rtol
    return _inverse_image(_norm_map(A), _basis(V, rtol), rtol)


def minI(A: object, B: object, rtol: float | None = None) -> np.ndarray:
    """Smallest A-invariant subspace containing im B: im B + A im B + ... + A^{n-1} im B.

    Notes
    -----
    R_0 = im B, R_{k+1} = R_k + A R_k, stopping when the dimension stops
    growing (at most n steps). It is the reachable subspace of (A, B), the minI
    of the paper's nomenclature and of conditions (12)-(17).
    """
    A = _square(A)
    B = _matrix(B, "B")
    n = A.shape[-1]
    _rows(B, n, "B")
    rtol = default_rtol(n, n) if rtol is None else rtol
    An = _norm_map(A)
    R = _image(B, rtol, 0.0)
    for _ in range(n):
        R_next = _image(_concat(R, An @ R), rtol, rtol)
        if dim(R_next) == dim(R):
            return R_next
        R = R_next
    return R


def maxV(A: object, B: object, E: object, rtol: float | None = None) -> np.ndarray:
    """Largest (A, im B)-controlled invariant contained in im E (V*), e.g. E = kernel(C).

    A subspace V is (A, im B)-controlled invariant when A V subset V + im B.

    Notes
    -----
    Basile and Marro's algorithm: V_0 = E, V_{k+1} = E cap A^{-1}(V_k + im B),
    a non-increasing sequence that stops in at most n steps.
    """
    A = _square(A)
    n = A.shape[-1]
    B = _matrix(B, "B")
    E = _matrix(E, "E")
    _rows(B, n, "B")
    _rows(E, n, "E")
    rtol = default_rtol(n, n) if rtol is None else rtol
    An = _norm_map(A)
    Eq = _image(E, rtol, 0.0)
    V = Eq
    for _ in range(n + 1):
        V_next = _intersect(Eq, _inverse_image(An, _image(_concat(V, B), rtol, 0.0), rtol), rtol)
        if dim(V_next) == dim(V):
            return V_next
        V = V_next
    return V


def minS(A: object, C: object, B: object, rtol: float | None = None) -> np.ndarray:
    """Smallest (A, im C)-conditioned invariant containing im B (S*), e.g. C = kernel(C_out).

    A subspace S is (A, im C)-conditioned invariant when A (S cap im C) subset S.

    Notes
    -----
    Basile and Marro's algorithm: S_0 = im B, S_{k+1} = im B + A (S_k cap im C),
    non-decreasing, at most n steps. Dual of `maxV`:
    maxV(A, B, E)^perp = minS(A^T, B^perp, E^perp).
    """
    A = _square(A)
    n = A.shape[-1]
    C = _matrix(C, "C")
    B = _matrix(B, "B")
    _rows(C, n, "C")
    _rows(B, n, "B")
    rtol = default_rtol(n, n) if rtol is None else rtol
    An = _norm_map(A)
    Bq, Cq = _image(B, rtol, 0.0), _basis(C, rtol)
    S = Bq
    for _ in range(n + 1):
        S_next = _image(_concat(Bq, An @ _intersect(S, Cq, rtol)), rtol, rtol)
        if dim(S_next) == dim(S):
            return S_next
        S = S_next
    return S


def z_sequence(
    A: object, B: object, C: object, F: object | None = None, steps: int | None = None, rtol: float | None = None
) -> list[np.ndarray]:
    """The sequence Z_0, ..., Z_steps of the projection condition, eq. (38).

    Z_0 = im B and Z_j = im B + A (Z_{j-1} cap F cap C).

    Parameters
    ----------
    A
        State matrix (n, n).
    B
        Input subspace (any matrix; its image is used).
    C
        The subspace ker C of the output (e.g. ``kernel(C_out)``), not the output matrix.
    F
        The candidate functional-controllability subspace; None means R^n.
    steps
        Last index; default n (the sequence is constant from then on).
    """
    A = _square(A)
    n = A.shape[-1]
    B, C = _matrix(B, "B"), _matrix(C, "C")
    _rows(B, n, "B")
    _rows(C, n, "C")
    F = np.eye(n) if F is None else _matrix(F, "F")
    _rows(F, n, "F")
    steps = n if steps is None else int(steps)
    if steps < 0:
        raise GeometryError(f"steps must be >= 0, got {steps}")
    rtol = default_rtol(n, n) if rtol is None else rtol
    An = _norm_map(A)
    Bq, Fq, Cq = _image(B, rtol, 0.0), _basis(F, rtol), _basis(C, rtol)
    Z = [Bq]
    for _ in range(steps):
        common = _intersect(Z[-1], Fq, rtol)
        if common.shape[-1]:
            common = _intersect(common, Cq, rtol)
        Z.append(_image(_concat(Bq, An @ common), rtol, rtol))
    return Z


def inclusion_residual(W: object, V: object, rtol: float | None = None) -> np.ndarray:
    """||(I - P_V) W||_2, with P_V the orthogonal projector on im V.

    For an orthonormal W it is the sine of the largest principal angle between
    im W and im V (0 when im W subset im V). Returns an array over the stack
    (a 0-d array for single matrices).
    """
    W = _matrix(W, "W")
    V = _matrix(V, "V")
    _rows(W, V.shape[-2], "W")
    Q = _basis(V, rtol)
    R = W - Q @ (np.swapaxes(Q, -1, -2) @ W)
    if R.shape[-1] == 0 or R.shape[-2] == 0:
        return np.zeros(R.shape[:-2])
    if R.shape[-1] == 1:
        return np.linalg.norm(R[..., 0], axis=-1)
    return np.linalg.svd(R, compute_uv=False)[..., 0]


def is_subspace(W: object, V: object, rtol: float | None = None) -> bool:
    """im W subset im V (for every element of a stack).

    Both are orthonormalised first; the inclusion holds when the sine of the
    largest principal angle is at most the rank tolerance.
    """
    W = _matrix(W, "W")
    V = _matrix(V, "V")
    n = V.shape[-2]
    tol = default_rtol(n, n) if rtol is None else rtol
    return bool(np.all(inclusion_residual(_basis(W, rtol), V, rtol) <= tol))


def subspaces_equal(V: object, W: object, rtol: float | None = None) -> bool:
    """im V = im W: equal dimensions and mutual inclusion."""
    Vq, Wq = _basis(_matrix(V, "V"), rtol), _basis(_matrix(W, "W"), rtol)
    return dim(Vq) == dim(Wq) and is_subspace(Vq, Wq, rtol) and is_subspace(Wq, Vq, rtol)
