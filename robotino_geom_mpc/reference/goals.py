"""The ``goals`` reference: hold a pose, then follow goal motions and timed paths as they arrive, C^3 throughout.

`GoalReference` is a `reference.trajectories.Reference` (the protocol `preview` and
the trajectory node stream), built from pieces: before the first piece it
holds its start pose; piece k runs from its start time until the next
piece's start (or for ever, at rest at its end pose). `go_to`, `follow`, `stop` and `shift`
start a new piece at a time t from the reference's full state at t
(p, v, a, j): the new piece is a `goal_motion.PolynomialMotion`, a `goal_motion.BrakingMotion`, a
`path_timing.PathMotion` or the running piece moved (`ShiftedMotion`) that starts from exactly that state, so the
stitched reference has no jump in position, velocity, acceleration or jerk
(replanning, a new goal during a motion). A refused goal (`GoalError`)
leaves the reference unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.reference.goal_motion import GRID_POINTS, BrakingMotion, GoalError, MotionLimits, \
    PolynomialMotion
from robotino_geom_mpc.reference.path_timing import PathMotion
from robotino_geom_mpc.reference.time_law import _Scalar, septic
from robotino_geom_mpc.reference.trajectories import Reference

__all__ = ["GoalReference", "SHIFT_SHARE", "ShiftedMotion"]

SHIFT_SHARE = 0.25  # a shift alone uses at most this share of each limit; shifted, a motion keeps 1 + this share
# the septic smoothstep's largest first, second and third derivatives (on the grid goal motions are checked on)
_SEPTIC_PEAKS = [float(np.abs(d).max()) for d in septic(np.linspace(0.0, 1.0, GRID_POINTS))[1:]]

class ShiftedMotion:
    """A piece that goes on with another (`base`, from `offset_s` into it) moved by shifts eased in with the septic:
    base(t + offset_s) + sum_i delta_i s((t - t_i) / T_i), s the septic smoothstep (`time_law.septic`: C^3, at rest
    at both ends), so it joins the base at t_i with p, v, a, j continuous and ends moved by sum_i delta_i.

    Parameters
    ----------
    base
        The piece moved (a `PolynomialMotion` or `path_timing.PathMotion`, never itself a `ShiftedMotion`).
    offset_s
        Where in `base` (its local time) this piece starts.
    shifts
        (t_i [s] local to this piece, delta_i (x, y, theta), T_i [s] > 0), in order.
    """

    def __init__(self, base: PolynomialMotion | PathMotion, offset_s: float,
                 shifts: list[tuple[float, np.ndarray, float]]) -> None:
        self.base, self.offset_s, self.shifts = base, offset_s, shifts
        self.duration_s = max(base.duration_s - offset_s, *(t0 + T for t0, _, T in shifts))
        self.goal = base.goal + sum(delta for _, delta, _ in shifts)

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """(4, n, 3): position, velocity, acceleration, jerk at local times t."""
        t = np.asarray(t, dtype=float)
        out = self.base.evaluate(t + self.offset_s)
        for t0, delta, T in self.shifts:
            s = septic((t - t0) / T)
            for k in range(4):
                out[k] += np.outer(s[k] / T**k, delta)
        return out


class GoalReference(Reference):
    """Hold `start`, then the pieces `go_to` and `follow` add (see the module docstring).

    Parameters
    ----------
    start
        The pose (x, y, theta) held until the first goal.
    hold_s
        The least `duration_s` (the run length a scenario gives when no goal is known in advance).

    Attributes
    ----------
    duration_s
        max(hold_s, the end of the last piece): after it the reference rests.
    """

    def __init__(self, start: tuple[float, float, float] = (0.0, 0.0, 0.0), hold_s: float = 10.0) -> None:
        self.name = "goals"
        self.start = checked_array(start, (3,), "start (x, y, theta)", GoalError)
        if not (math.isfinite(hold_s) and hold_s >= 0.0):
            raise GoalError(f"hold_s must be >= 0 and finite, got {hold_s!r}")
        self.hold_s = float(hold_s)
        self.starts: list[float] = []  # start time of each piece
        self.pieces: list[PolynomialMotion | PathMotion | ShiftedMotion] = []
        self.duration_s = self.hold_s

    @property
    def motion_end_s(self) -> float:
        """When the last piece comes to rest (0 before any): after it the reference rests; `duration_s` also covers
        ``hold_s``.
        """
        return self.starts[-1] + self.pieces[-1].duration_s if self.pieces else 0.0

    def state(self, t: float) -> np.ndarray:
        """(4, 3): position, velocity, acceleration, jerk of (x, y, theta) at time t."""
        return np.array(self.sample(np.array([float(t)]))).reshape(4, 3)

    def go_to(self, t: float, goal: np.ndarray, limits: MotionLimits) -> PolynomialMotion | None:
        """From time t on, move to `goal` (x, y, theta absolute) and rest there; None if already resting there.

        Raises
        ------
        GoalError
            Non-finite goal or time, or no motion within the limits (the reference is then unchanged).
        """
        self._check_time(t)
        piece = PolynomialMotion.within(self.state(t), goal, limits)
        self._add(t, piece)
        return piece

    def follow(self, t: float, poses: np.ndarray, limits: MotionLimits) -> PathMotion:
        """From time t on, follow the poses (m, 3) (theta absolute) and rest at the last one.

        Raises
        ------
        GoalError
            Empty or non-finite poses, a non-finite time, or no timing within the limits (reference unchanged).
        """
        self._check_time(t)
        piece = PathMotion(self.state(t), poses, limits)
        self._add(t, piece)
        return piece

    def stop(self, t: float, limits: MotionLimits) -> BrakingMotion | None:
        """From time t on, brake within `limits` to rest where that brings the reference; None if at rest already.

        Raises
        ------
        GoalError
            A non-finite time, or no stop within the limits (the reference is then unchanged).
        """
        self._check_time(t)
        piece = BrakingMotion.stopping(self.state(t), limits)
        self._add(t, piece)
        return piece

    def shift(self, t: float, delta: np.ndarray, limits: MotionLimits) -> ShiftedMotion:
        """From time t on, move the rest of the reference by `delta` (x, y, theta), eased in with the septic over the
        time the current piece has left (at least the shortest for which the shift alone keeps `SHIFT_SHARE` of the
        limits): its end moves by `delta`, its course by at most |delta| on the way (a replan of the same route, a
        localization correction), with no retiming. The shifted reference keeps (1 + `SHIFT_SHARE`) times the limits
        (the motion it rides on may use them all): a replan that moves the end a little costs that much more than a
        retimed one, not a slowdown.

        Raises
        ------
        GoalError
            No piece runs at t, a non-finite shift, or the shifted reference would leave (1 + `SHIFT_SHARE`) times the
            limits (the rim speed; checked on a dense grid): the reference is then unchanged.
        """
        self._check_time(t)
        d = checked_array(delta, (3,), "shift (x, y, theta)", GoalError)
        running = [index for index, start in enumerate(self.starts) if start <= t]
        if not running:
            raise GoalError("no motion to shift: the reference holds its start")
        piece, since = self.pieces[running[-1]], t - self.starts[running[-1]]
        base, offset, shifts = (piece.base, piece.offset_s + since,
                                [(t0 - since, dk, T) for t0, dk, T in piece.shifts]) \
            if isinstance(piece, ShiftedMotion) else (piece, since, [])
        bounds = limits.bounds
        least = max((abs(d[axis]) * _SEPTIC_PEAKS[order] / (SHIFT_SHARE * bounds[order, axis])) ** (1.0 / (order + 1))
                    for order in range(3) for axis in range(3))
        moved = ShiftedMotion(base, offset, shifts + [(0.0, d, max(piece.duration_s - since, least, 1e-3))])
        grid = np.linspace(0.0, moved.duration_s, max(GRID_POINTS, int(moved.duration_s / 0.01)))
        p, v, a, j = moved.evaluate(grid)
        if limits.usage(p[:, 2], v, a, j) > 1.0 + SHIFT_SHARE:
            raise GoalError(f"a shift by {np.round(d, 4).tolist()} leaves the limits; the reference is unchanged")
        self._add(t, moved)
        return moved

    @staticmethod
    def _check_time(t: float) -> None:
        if not math.isfinite(t) or t < 0.0:
            raise GoalError(f"a goal's start time must be finite and >= 0, got {t!r}")

    def _add(self, t: float, piece: PolynomialMotion | PathMotion | ShiftedMotion | None) -> None:
        # pieces that would start at or after t are replaced; the current one ends at t
        keep = sum(1 for s in self.starts if s < t)
        del self.starts[keep:], self.pieces[keep:]
        if piece is not None:
            self.starts.append(float(t))
            self.pieces.append(piece)
            self.duration_s = max(self.hold_s, t + piece.duration_s)
        elif self.pieces:  # already at rest at the goal: hold the state at t
            self.duration_s = max(self.hold_s, t)

    def _kernel(self, t, xp, derivatives: bool) -> list:  # noqa: ANN001
        times = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.zeros((4, len(times), 3))
        out[0] = self.start
        if self.pieces:
            index = np.searchsorted(np.array(self.starts), times, side="right") - 1
            for k in np.unique(index[index >= 0]):
                mask = index == k
                out[:, mask] = self.pieces[k].evaluate(times[mask] - self.starts[k])
        values = out if derivatives else out[:1]
        if xp is _Scalar and np.ndim(t) == 0:
            return [tuple(float(v) for v in value[0]) for value in values]
        return [tuple(value.T) for value in values]
