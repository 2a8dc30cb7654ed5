"""A C^3, time-parameterised trajectory through planner poses (a nav_msgs/Path), within `MotionLimits`.

Geometry: the reference's pose and the path's poses are knots in (x, y, l theta), l the wheel distance (a pure
rotation in place has the length its wheels roll, so poses that differ in heading only are distinct knots), and
the parameter u is the chord length in that metric. Headings are the poses' own (absolute, already unwrapped by the
caller). The knots are cut into segments where the path turns by more than `SPLIT_ANGLE_RAD` from one chord to the
next (a planner's corner, a turn in place between two straight legs, a reversal): the robot, holonomic, comes to
rest there, and each segment is a quintic interpolating spline X(u) = (x, y, theta)(u) through its knots
(`scipy.interpolate.make_interp_spline`, k = 5, second and third derivatives zero at both ends). A spline through a
sharp corner would ring, and its curvature would hold the whole path to a crawl.

Time law per segment: u(t) = phi(t), `time_law._RampedPhase` (the rate ramps in with the septic smoothstep over
rho T, cruises, ramps out: C^4, at rest with zero acceleration and jerk at both ends), derivatives of X(u(t)) by
Faa di Bruno (`time_law._compose`). Its duration T is the shortest (`goal_motion.shortest_duration`) for which the
segment stays within the limits on a dense grid, for the best of the ramp fractions `RAMP_FRACTIONS` (a long
straight leg cruises; a short or curved one is all ramp). A quintic spline is C^4 in u, so X(u(t)) is C^3, and the
segments join at rest: the trajectory is C^3 throughout.

Start while moving: the path starts at the reference's position, at rest; the reference's velocity, acceleration
and jerk at the switch are carried by a blend B(t), the degree-7 state-to-rest polynomial of `reference.goal_motion`
from (0, v, a, j) to 0, planned within half the limits, added to the first segment, whose duration is then the
shortest for which the sum stays within the limits (it exists: the blend uses at most half of each limit and the
segment's share shrinks as its T grows); the next segment starts when both have ended. p, v, a, j are continuous
at the switch.
"""

from __future__ import annotations

import math

import numpy as np

from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.reference.goal_motion import GoalError, MotionLimits, PolynomialMotion, shortest_duration
from robotino_geom_mpc.reference.time_law import _compose, _RampedPhase, _Vector

__all__ = ["PathMotion", "load_splines"]

GRID_PER_KNOT = 30  # samples per knot of a segment on which the limits are checked (at least `MIN_GRID`)
MIN_GRID = 250
SPLIT_ANGLE_RAD = math.radians(30.0)  # a turn sharper than this between two chords: rest there
RAMP_FRACTIONS = (0.45, 0.3, 0.15)  # rho: the share of T each ramp of a segment's time law takes (< 1/2)
_DUPLICATE = 1e-9  # poses closer than this (in the chord metric) are one knot


def load_splines() -> None:
    """Import scipy's splines now (0.3-0.7 s) rather than at the first path: a node that plans paths in its callbacks
    would stall its previews that long, and a controller's watchdog stops the robot for less.
    """
    import scipy.interpolate  # noqa: F401


def _halved(limits: MotionLimits) -> MotionLimits:
    """Half of every limit (the blend's share)."""
    halves = {k: 0.5 * getattr(limits, k) for k in limits.__dataclass_fields__ if k != "robot"}
    return MotionLimits(**halves, robot=limits.robot)


def _corners(knots: np.ndarray, weights: np.ndarray) -> list[int]:
    """Indices of the inner knots where the chord direction (in the weighted metric) turns by > `SPLIT_ANGLE_RAD`."""
    chords = np.diff(knots, axis=0) * weights
    unit = chords / np.linalg.norm(chords, axis=1)[:, None]
    cosines = np.einsum("ij,ij->i", unit[:-1], unit[1:])
    return (np.flatnonzero(cosines < math.cos(SPLIT_ANGLE_RAD)) + 1).tolist()


class _Segment:
    """A rest-to-rest piece of the path: the quintic spline through `knots` (k >= 2) timed by a ramped phase."""

    def __init__(self, knots: np.ndarray, weights: np.ndarray) -> None:
        from scipy.interpolate import make_interp_spline  # here: 0.7 s of import every node would pay

        u = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(knots, axis=0) * weights, axis=1))))
        self.length = float(u[-1])
        bc = [(2, np.zeros(3)), (3, np.zeros(3))]
        self.spline = make_interp_spline(u, knots, k=5, bc_type=(bc, bc))
        self._derivs = [self.spline.derivative(k) for k in (1, 2, 3)]
        self.time(1.0, RAMP_FRACTIONS[0])  # until `PathMotion` times it

    def time(self, duration_s: float, ramp_fraction: float) -> None:
        """Traverse the segment in `duration_s` with ramps of `ramp_fraction` of it."""
        ramp = ramp_fraction * duration_s
        self.phase = _RampedPhase(self.length / (duration_s - ramp), ramp, self.length, "path")

    @property
    def duration_s(self) -> float:
        return self.phase.duration_s

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """(4, n, 3): position, velocity, acceleration, jerk at local times t (clipped: rest at the ends)."""
        law = self.phase.evaluate(t, _Vector, True)
        f = [self.spline(law[0])] + [d(law[0]) for d in self._derivs]
        return np.array(_compose([fk.T for fk in f], law)).transpose(0, 2, 1)


class PathMotion:
    """The timed path of the module docstring; `evaluate` gives (4, n, 3) at local times t >= 0.

    Parameters
    ----------
    state
        (4, 3): position, velocity, acceleration, jerk of (x, y, theta) when the path starts.
    poses
        (m, 3) path poses (x, y, theta) with theta absolute (unwrapped), m >= 1.
    limits
        The limits the whole motion keeps.

    Attributes
    ----------
    segments, starts
        The rest-to-rest segments and their start times (local) [s].
    duration_s
        The end of the last segment (and of the blend); after it the motion rests at the last pose.
    goal
        The last pose.

    Raises
    ------
    GoalError
        Empty or non-finite poses, or no duration within `goal_motion.MAX_DURATION_S` keeps the limits.
    """

    def __init__(self, state: np.ndarray, poses: np.ndarray, limits: MotionLimits) -> None:
        s = checked_array(state, (4, 3), "start state (p, v, a, j)", GoalError)
        pts = np.asarray(poses, dtype=float) if not isinstance(poses, np.ndarray) else poses.astype(float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise GoalError(f"a path needs at least one pose (x, y, theta), got shape {pts.shape}")
        if not np.isfinite(pts).all():
            raise GoalError("path poses must be finite")
        knots = np.vstack((s[0], pts))
        weights = np.array([1.0, 1.0, limits.robot.l])
        keep = np.concatenate(([True], np.linalg.norm(np.diff(knots, axis=0) * weights, axis=1) > _DUPLICATE))
        knots = knots[keep]
        self.goal = knots[-1].copy()
        self._start = s[0].copy()
        self.blend = PolynomialMotion.within(np.vstack((np.zeros(3), s[1:])), np.zeros(3), _halved(limits))
        blend_s = 0.0 if self.blend is None else self.blend.duration_s
        self.segments: list[_Segment] = []
        self.starts: list[float] = []
        if len(knots) > 1:
            cuts = [0, *_corners(knots, weights), len(knots) - 1]
            self.segments = [_Segment(knots[a:b + 1], weights) for a, b in zip(cuts[:-1], cuts[1:])]
        start = 0.0
        for k, segment in enumerate(self.segments):
            self._time(segment, limits, self.blend if k == 0 else None, len(segment.spline.t))
            self.starts.append(start)
            start += max(segment.duration_s, blend_s if k == 0 else 0.0)
        self.duration_s = max(start, blend_s)

    @staticmethod
    def _time(segment: _Segment, limits: MotionLimits, blend: PolynomialMotion | None, knots: int) -> None:
        """The shortest timing of `segment` (plus `blend` from t = 0) within `limits`, over `RAMP_FRACTIONS`."""
        grid = max(MIN_GRID, GRID_PER_KNOT * knots)
        blend_s = 0.0 if blend is None else blend.duration_s
        best: tuple[float, float] | None = None
        for rho in RAMP_FRACTIONS:

            def usage(T: float, rho: float = rho) -> float:
                segment.time(T, rho)
                t = np.linspace(0.0, max(T, blend_s), grid)
                p, v, a, j = segment.evaluate(t) + (0.0 if blend is None else blend.evaluate(t))
                return limits.usage(p[:, 2], v, a, j)

            T = shortest_duration(usage)
            if best is None or T < best[0]:
                best = (T, rho)
        assert best is not None
        segment.time(*best)

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """(4, n, 3): position, velocity, acceleration, jerk at local times t (rest at the last pose after the end)."""
        t = np.asarray(t, dtype=float)
        out = np.zeros((4, len(t), 3))
        out[0] = self._start
        if self.segments:
            index = np.clip(np.searchsorted(np.array(self.starts), t, side="right") - 1, 0, None)
            for k in np.unique(index):
                mask = index == k
                out[:, mask] = self.segments[k].evaluate(t[mask] - self.starts[k])
        if self.blend is not None:
            out = out + self.blend.evaluate(t)
        return out
