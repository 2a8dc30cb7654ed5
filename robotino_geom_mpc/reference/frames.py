"""Frame transforms without tf2: rigid transforms, and a tree of the newest transform of each frame's edge.

A transform T = (t, q) maps coordinates in a child frame to coordinates in its parent frame,

    p_parent = R(q) p_child + t,

with t the child's origin in the parent frame and q = (x, y, z, w) the unit quaternion (geometry_msgs' order)
of the child's axes in the parent's: a geometry_msgs/TransformStamped with header.frame_id the parent and
child_frame_id the child, as /tf carries it. Products read right to left, (T_ab @ T_bc) p = T_ab (T_bc p), so
T_ab @ T_bc = T_ac. The frames are REP-105's (``map`` -> ``odom`` -> ``base_link``, each the parent of the
next) with REP-103's axes (x forward, y left, z up; yaw counter-clockwise about +z).

`TransformTree` holds the frames as tf2 does: each child has one parent, so the frames form trees.
`TransformTree.lookup` (target, source) is tf2's lookupTransform(target_frame, source_frame): the T with
p_target = T p_source, found through the common ancestor a of the two frames as T_at^-1 T_as, each factor the
product of the edges from a down to the frame. It is tf2's lookup at time 0 ("latest"), without interpolation:
each edge holds only its newest transform. Where this differs from tf2:

* newest means the last one set, not the largest stamp (tf2's cache orders by stamp). One writer's samples
  arrive in order over DDS, and a clock that goes back (a simulation restarted) needs no clearing of old data.
* tf2's latest lookup takes the chain at its latest common time, the oldest of the edges' newest stamps, and
  interpolates the others back to it; here each edge's newest value is used, and ``max_age_s`` bounds how
  old a dynamic edge may be.
* a transform that would close a loop is refused when it is set (tf2 finds the loop at lookup).
* a leading '/' is stripped from the frame ids of lookups as well as of transforms (tf2 refuses it in a lookup).
* a frame's newest transform decides whether its edge is static (tf2 keeps the kind of the first).

A planar pose (x, y, yaw) of the robot is a frame with the transform (x, y, 0) and the rotation yaw about z.
`transform_planar` moves such poses (a nav_msgs/Path given in ``map``, into ``odom``) with a transform whose
rotation is about z (`Rigid.planar`); a vertical offset of the frames leaves x, y and yaw as they are.
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["FrameError", "NORM_TOLERANCE", "PLANAR_TOLERANCE", "Rigid", "TransformTree", "transform_planar"]

# | |q| - 1 | above this is refused, below it q is normalized: the controller's quaternion_norm_tolerance
# default (tf2 is looser: |q|^2 within 1e-2 of 1, about 5e-3 on |q|)
NORM_TOLERANCE = 1e-3
PLANAR_TOLERANCE = 1e-6  # sqrt(q_x^2 + q_y^2) of a unit q above this is no rotation about z alone (~2e-6 rad tilt)


class FrameError(RobotinoError, ValueError):
    """A transform or lookup that is refused.

    Attributes
    ----------
    reason
        Short key of the refusal: ``shape``, ``non_finite``, ``not_unit`` (a quaternion's norm), ``empty_frame``,
        ``same_frame`` (parent = child), ``loop``, ``unknown_frame``, ``no_path`` (frames in two trees),
        ``stale``, ``usage`` (lookup arguments), ``not_planar``.
    """

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


def _vector(value: object, size: int, name: str) -> np.ndarray:
    """`value` as a new float array of `size` finite numbers, else `FrameError` (``shape``, ``non_finite``)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise FrameError(f"{name} must be {size} numbers: {exc}", "shape") from None
    if arr.shape != (size,):
        raise FrameError(f"{name} must have shape ({size},), got {arr.shape}", "shape")
    if not np.isfinite(arr).all():
        raise FrameError(f"{name} must be finite, got {arr.tolist()}", "non_finite")
    return arr


class Rigid:
    """A rigid transform: p -> R(rotation) p + translation (see the module docstring).

    Parameters
    ----------
    translation
        (3,) t [m].
    rotation
        (4,) quaternion (x, y, z, w); its norm within `NORM_TOLERANCE` of 1, normalized here.

    Attributes
    ----------
    translation, rotation
        The (3,) t and the (4,) unit quaternion, read-only arrays.

    Raises
    ------
    FrameError
        ``shape``, ``non_finite`` or ``not_unit``.
    """

    __slots__ = ("translation", "rotation")

    def __init__(self, translation: ArrayLike, rotation: ArrayLike) -> None:
        t = _vector(translation, 3, "translation")
        q = _vector(rotation, 4, "rotation (x, y, z, w)")
        norm = math.sqrt(float(q @ q))
        if not abs(norm - 1.0) <= NORM_TOLERANCE:
            raise FrameError(f"rotation {q.tolist()} has norm {norm:.6g}, not 1 within {NORM_TOLERANCE:g}", "not_unit")
        q /= norm
        t.setflags(write=False)
        q.setflags(write=False)
        self.translation, self.rotation = t, q

    def __repr__(self) -> str:
        return f"Rigid(translation={self.translation.tolist()}, rotation={self.rotation.tolist()})"

    @classmethod
    def identity(cls) -> Rigid:
        """The transform that moves nothing."""
        return cls(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))

    def _matrix(self) -> np.ndarray:
        """(3, 3) R of the unit quaternion."""
        x, y, z, w = self.rotation.tolist()
        return np.array([
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ])

    def __matmul__(self, other: Rigid) -> Rigid:
        """self @ other: `other`, then self (T_ab @ T_bc = T_ac); the rotation is the Hamilton product q_ab q_bc."""
        x1, y1, z1, w1 = self.rotation.tolist()
        x2, y2, z2, w2 = other.rotation.tolist()
        rotation = (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                    w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                    w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
                    w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)
        return Rigid(self.apply(other.translation), np.array(rotation))

    def inverse(self) -> Rigid:
        """T^-1: p -> R^T (p - t), the rotation the conjugate quaternion."""
        x, y, z, w = self.rotation.tolist()
        return Rigid(-(self._matrix().T @ self.translation), np.array([-x, -y, -z, w]))

    def apply(self, points: ArrayLike) -> np.ndarray:
        """R p + t of each point: `points` (3,) or (n, 3) [m], the result of the same shape."""
        return np.asarray(points, dtype=float) @ self._matrix().T + self.translation

    def planar(self) -> tuple[float, float, float]:
        """(x, y, yaw) of a rotation about z: the translation's x and y (its z is ignored), yaw in (-pi, pi].

        Raises
        ------
        FrameError
            ``not_planar``: the rotation tilts z (sqrt(q_x^2 + q_y^2) > `PLANAR_TOLERANCE`).
        """
        x, y, z, w = self.rotation.tolist()
        if math.hypot(x, y) > PLANAR_TOLERANCE:
            raise FrameError(f"rotation {self.rotation.tolist()} is not about z alone", "not_planar")
        tx, ty, _ = self.translation.tolist()
        return tx, ty, math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def transform_planar(transform: Rigid, poses: ArrayLike) -> np.ndarray:
    """Planar poses (x, y, yaw) in a source frame, in the target frame of `transform` (T_target_source).

    (x', y') = R(psi) (x, y) + (t_x, t_y) and yaw' = yaw + psi, with (t_x, t_y, psi) = ``transform.planar()``,
    psi in (-pi, pi]. The yaw is not wrapped: yaw' - yaw is psi, so headings unwrapped along a path stay so.

    Parameters
    ----------
    poses
        (3,) or (n, 3).

    Returns
    -------
    The poses in the target frame, of the shape of `poses`.

    Raises
    ------
    FrameError
        ``not_planar`` (`Rigid.planar`), ``shape`` or ``non_finite`` poses.
    """
    tx, ty, psi = transform.planar()
    p = np.asarray(poses, dtype=float)
    if p.ndim not in (1, 2) or p.shape[-1] != 3:
        raise FrameError(f"poses must have shape (3,) or (n, 3), got {p.shape}", "shape")
    if not np.isfinite(p).all():
        raise FrameError("poses must be finite", "non_finite")
    c, s = math.cos(psi), math.sin(psi)
    out = np.empty_like(p)
    out[..., 0] = c * p[..., 0] - s * p[..., 1] + tx
    out[..., 1] = s * p[..., 0] + c * p[..., 1] + ty
    out[..., 2] = p[..., 2] + psi
    return out


def _frame_id(frame: str, what: str) -> str:
    """`frame` without one leading '/' (tf2's stripSlash); `FrameError` ``empty_frame`` if nothing is left."""
    stripped = frame[1:] if frame.startswith("/") else frame
    if not stripped:
        raise FrameError(f"the {what} frame id {frame!r} is empty", "empty_frame")
    return stripped


class _Edge(NamedTuple):
    """A child frame's newest transform T_parent_child."""

    parent: str
    transform: Rigid
    stamp_ns: int
    static: bool


class TransformTree:
    """The newest transform of each parent -> child edge, and lookups through the trees (module docstring).

    `set` and `lookup` may be called from different threads (a listener's callbacks, an action server's).
    """

    def __init__(self) -> None:
        self._edges: dict[str, _Edge] = {}  # child -> its edge
        self._frames: set[str] = set()  # every frame seen (a parent left without children stays known, as in tf2)
        self._lock = threading.Lock()

    def set(self, parent: str, child: str, translation: ArrayLike, rotation_xyzw: ArrayLike, stamp_ns: int,
            static: bool = False) -> None:
        """Make T_parent_child (`Rigid` of the translation and rotation) `child`'s edge.

        It replaces the child's edge, also one from another parent (the child moves to `parent`, as in tf2).
        A static edge is never stale.

        Raises
        ------
        FrameError
            ``empty_frame``, ``same_frame``, ``shape``, ``non_finite``, ``not_unit``, or ``loop`` if `child` is an
            ancestor of `parent`; the tree is then unchanged.
        """
        parent, child = _frame_id(parent, "parent"), _frame_id(child, "child")
        if parent == child:
            raise FrameError(f"a transform from frame {parent!r} to itself", "same_frame")
        transform = Rigid(translation, rotation_xyzw)
        with self._lock:
            ancestor: str | None = parent
            while ancestor is not None:
                if ancestor == child:
                    raise FrameError(f"{parent!r} -> {child!r} would close a loop: {child!r} is an ancestor of "
                                     f"{parent!r}", "loop")
                edge = self._edges.get(ancestor)
                ancestor = edge.parent if edge is not None else None
            self._edges[child] = _Edge(parent, transform, int(stamp_ns), bool(static))
            self._frames.update((parent, child))

    def _up(self, frame: str) -> tuple[list[str], list[_Edge]]:
        """The frames from `frame` up to its root (`frame` first) and the edges between them."""
        frames, edges = [frame], []
        edge = self._edges.get(frame)
        while edge is not None:
            edges.append(edge)
            frames.append(edge.parent)
            edge = self._edges.get(edge.parent)
        return frames, edges

    def lookup(self, target: str, source: str, now_ns: int | None = None, max_age_s: float | None = None) -> Rigid:
        """T_target_source, p_target = T p_source: tf2's lookupTransform(target, source) at time 0 ("latest").

        The identity when the frames are equal (known or not, as in tf2).

        Parameters
        ----------
        now_ns, max_age_s
            Both or neither: with both, a dynamic edge of the chain whose stamp is more than `max_age_s` before
            `now_ns` is refused (``stale``).

        Raises
        ------
        FrameError
            ``empty_frame``, ``unknown_frame``, ``no_path`` (the frames are in two trees), ``stale``, ``usage``.
        """
        target, source = _frame_id(target, "target"), _frame_id(source, "source")
        if (now_ns is None) != (max_age_s is None):
            raise FrameError("now_ns and max_age_s are given together or not at all", "usage")
        if max_age_s is not None and not (math.isfinite(max_age_s) and max_age_s >= 0.0):
            raise FrameError(f"max_age_s must be >= 0 and finite, got {max_age_s!r}", "usage")
        if target == source:
            return Rigid.identity()
        with self._lock:
            unknown = [frame for frame in (target, source) if frame not in self._frames]
            if unknown:
                raise FrameError(f"unknown frame {' and '.join(map(repr, unknown))}", "unknown_frame")
            source_frames, source_edges = self._up(source)
            target_frames, target_edges = self._up(target)
        common = set(source_frames).intersection(target_frames)
        if not common:
            raise FrameError(f"{target!r} and {source!r} are in two trees (roots {target_frames[-1]!r} and "
                             f"{source_frames[-1]!r})", "no_path")
        # the lowest common ancestor: the first of the source's ancestors that the target has too
        ancestor = next(frame for frame in source_frames if frame in common)
        source_edges = source_edges[:source_frames.index(ancestor)]
        target_edges = target_edges[:target_frames.index(ancestor)]
        if now_ns is not None and max_age_s is not None:
            for edge, child in [*zip(source_edges, source_frames), *zip(target_edges, target_frames)]:
                age_s = (now_ns - edge.stamp_ns) * 1e-9
                if not edge.static and age_s > max_age_s:
                    raise FrameError(f"{edge.parent!r} -> {child!r} is {age_s:.3f} s old, more than {max_age_s:g} s",
                                     "stale")
        return _down(target_edges).inverse() @ _down(source_edges)


def _down(edges: list[_Edge]) -> Rigid:
    """T_a_frame of the edges from a frame up to its ancestor a (the frame's own edge first)."""
    transform = Rigid.identity()
    for edge in edges:
        transform = edge.transform @ transform
    return transform
