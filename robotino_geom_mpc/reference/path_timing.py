"""A C^3, time-parameterised trajectory through planner poses (a nav_msgs/Path), within `MotionLimits`.

Geometry: a quintic interpolating spline X(u) = (x, y, theta)(u) through the
reference's pose and the path's poses (`scipy.interpolate.make_interp_spline`,
k = 5, second and third derivatives zero at both ends). The parameter u is the
chord length in the metric sqrt(dx^2 + dy^2 + (l dtheta)^2), l the wheel
distance: a pure rotation in place has the length its wheels roll, so poses
that differ in heading only are distinct knots. Heading: the poses' own
(absolute, already unwrapped by the caller), interpolated like x and y.
A quintic spline is C^4 in u, so X(u(t)) is C^3 in t for a C^3 time law; between
poses it may overshoot a little (a few % of a turn in place that reverses).

Time law: u(t) = U s(t / T_s), s the septic smoothstep (`reference.time_law.septic`):
at rest at both ends with zero acceleration and jerk, derivatives of X(u(t))
by Faa di Bruno (`reference.time_law._compose`).

Start while moving: the path starts at the reference's position, at rest; the
reference's velocity, acceleration and jerk at the switch are carried by a
blend B(t), the degree-7 state-to-rest polynomial of `reference.goal_motion`
from (0, v, a, j) to 0, planned within half the limits. The trajectory is
X(u(t)) + B(t): p, v, a, j are continuous at the switch. T_s is the shortest
duration (`goal_motion.shortest_duration`) for which the sum stays within
the limits on a dense grid; it exists because the blend alone uses at most
half of each and the path's share shrinks as T_s grows.
"""

from __future__ import annotations

import numpy as np

from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.reference.goal_motion import GoalError, MotionLimits, PolynomialMotion, shortest_duration
from robotino_geom_mpc.reference.time_law import _compose, _septic, _Vector

__all__ = ["PathMotion"]

GRID_PER_KNOT = 30  # samples per path pose on which the limits are checked (at least `MIN_GRID`)
MIN_GRID = 250
_DUPLICATE = 1e-9  # poses closer than this (in the chord metric) are one knot


def _halved(limits: MotionLimits) -> MotionLimits:
    """Half of every limit (the blend's share)."""
    halves = {k: 0.5 * getattr(limits, k) for k in limits.__dataclass_fields__ if k != "robot"}
    return MotionLimits(**halves, robot=limits.robot)


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
    duration_s
        max(T_s, blend duration); after it the motion rests at the last pose.
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
        steps = np.linalg.norm(np.diff(knots, axis=0) * weights, axis=1)
        keep = np.concatenate(([True], steps > _DUPLICATE))
        knots, u = knots[keep], np.concatenate(([0.0], np.cumsum(steps[steps > _DUPLICATE])))
        self.goal = knots[-1].copy()
        self.length = float(u[-1])
        self.spline = None
        if len(knots) > 1:
            bc = [(2, np.zeros(3)), (3, np.zeros(3))]
            from scipy.interpolate import make_interp_spline  # here: 0.7 s of import every node would pay

            self.spline = make_interp_spline(u, knots, k=5, bc_type=(bc, bc))
            self._derivs = [self.spline.derivative(k) for k in (1, 2, 3)]
        self._start = s[0].copy()
        self.blend = PolynomialMotion.within(np.vstack((np.zeros(3), s[1:])), np.zeros(3), _halved(limits))
        blend_s = 0.0 if self.blend is None else self.blend.duration_s
        self.path_s = 0.0
        if self.spline is not None:
            grid = max(MIN_GRID, GRID_PER_KNOT * len(knots))

            def usage(T: float) -> float:
                self.path_s = T
                t = np.linspace(0.0, max(T, blend_s), grid)
                p, v, a, j = self.evaluate(t)
                return limits.usage(p[:, 2], v, a, j)

            self.path_s = shortest_duration(usage)
        self.duration_s = max(self.path_s, blend_s)

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """(4, n, 3): position, velocity, acceleration, jerk at local times t (rest at the last pose after the end)."""
        t = np.asarray(t, dtype=float)
        if self.spline is None:
            out = np.zeros((4, len(t), 3))
            out[0] = self._start
        else:
            s = _septic(t / self.path_s, _Vector)
            rates = (1.0, 1.0 / self.path_s, self.path_s**-2, self.path_s**-3)
            law = tuple(self.length * sk * rk for sk, rk in zip(s, rates))
            f = [self.spline(law[0])] + [d(law[0]) for d in self._derivs]
            out = np.array(_compose([fk.T for fk in f], law)).transpose(0, 2, 1)
        if self.blend is not None:
            out = out + self.blend.evaluate(t)
        return out
