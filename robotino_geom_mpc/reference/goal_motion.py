"""C^3 motions from any reference state to a goal at rest, within per-axis and wheel-speed limits.

A goal motion starts at the reference's full state (position, velocity,
acceleration and jerk of x, y, theta at the time the goal arrives) and ends
at rest at the goal. Per axis it is the degree-7 polynomial in
tau = t / T that matches the four values at each end (8 conditions, 8
coefficients), so a motion joins the reference it replaces with p, v, a and
j continuous (C^3 at the switch, Remark 1 / Theorem 1 ask for C^3) and ends
C^3 at rest. From rest it is the septic rest-to-rest law of
`reference.time_law.septic`.

All three axes share one duration T: the shortest for which, on a dense
grid, every axis stays within its velocity, acceleration and jerk limit and
every wheel's rim speed v_i = d_i(theta) . (x', y') + l theta'
(`model.dynamics.wheel_rim_speeds`) within the rim-speed limit (`MotionLimits`).
Short durations break the limits, long ones keep them (the motion's
derivatives shrink like 1/T, 1/T^2, 1/T^3 apart from the initial state,
which the previous motion kept within the limits), so T is found by a
geometric scan and a bisection (`shortest_duration`). Exception: a new goal from a state at a limit
(mid-motion, accelerating hard) may admit no continuation within it, since this polynomial's acceleration
and jerk overshoot the initial ones by a factor that does not shrink with T; then the duration with the
least excess is taken (at most `MAX_OVERSHOOT` times the limits, else `GoalError`). From rest (every goal
the robot waits for) the limits always hold. Plain numpy: no ROS.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.model.dynamics import wheel_rim_speeds
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = ["BrakingMotion", "GoalError", "MotionLimits", "PolynomialMotion", "shortest_duration", "nominal_rim_speed"]

GRID_POINTS = 200  # samples per motion on which the limits are checked
LIMIT_MARGIN = 0.998  # the planner keeps this fraction of each limit (the grid may miss a peak by ~5e-4)
MAX_DURATION_S = 600.0
MAX_OVERSHOOT = 4.0  # a replan from a state near the limits may exceed them by at most this factor
AT_REST = 1e-12  # a state whose velocities, accelerations and jerks are all at most this is at rest (a stop's end)


class GoalError(RobotinoError, ValueError):
    """A goal or path that cannot be planned: non-finite, empty, or unreachable within the limits."""


def nominal_rim_speed(robot: RobotinoParams) -> float:
    """The wheels' rim speed at the motor's nominal speed: rpm 2 pi / 60 / gear r [m/s] (0.94 m/s on Robotino 3)."""
    return robot.nominal_speed_rpm * 2.0 * math.pi / 60.0 / robot.gear_ratio * robot.r


@dataclass(frozen=True)
class MotionLimits:
    """Limits of a planned motion: per axis |v|, |a|, |j| (x and y share the linear ones) and the wheels' rim speed.

    Attributes
    ----------
    velocity_mps, acceleration_mps2, jerk_mps3
        Bounds on |x'|, |y'| [m/s], |x''|, |y''| [m/s^2], |x'''|, |y'''| [m/s^3] (each axis of ``odom``).
    angular_velocity_radps, angular_acceleration_radps2, angular_jerk_radps3
        Bounds on |theta'|, |theta''|, |theta'''|.
    rim_speed_mps
        Bound on every wheel's rim speed |v_i| [m/s].
    robot
        The robot whose wheel kinematics give the rim speeds.
    """

    velocity_mps: float
    acceleration_mps2: float
    jerk_mps3: float
    angular_velocity_radps: float
    angular_acceleration_radps2: float
    angular_jerk_radps3: float
    rim_speed_mps: float
    robot: RobotinoParams

    def __post_init__(self) -> None:
        for name in ("velocity_mps", "acceleration_mps2", "jerk_mps3", "angular_velocity_radps",
                     "angular_acceleration_radps2", "angular_jerk_radps3", "rim_speed_mps"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise GoalError(f"limit {name} must be a positive finite number, got {value!r}")

    @property
    def bounds(self) -> np.ndarray:
        """(3, 3): rows velocity, acceleration, jerk; columns x, y, theta."""
        lin = (self.velocity_mps, self.acceleration_mps2, self.jerk_mps3)
        ang = (self.angular_velocity_radps, self.angular_acceleration_radps2, self.angular_jerk_radps3)
        return np.array([[v, v, w] for v, w in zip(lin, ang)])

    def usage(self, theta: np.ndarray, vel: np.ndarray, acc: np.ndarray, jerk: np.ndarray) -> float:
        """The largest ratio |value| / limit over samples (theta (n,), vel/acc/jerk (n, 3)); <= 1: within.

        Above `LIMIT_MARGIN` on an axis, that axis's ratio (the rim speeds are not computed then).

        Rim speeds are computed with `model.dynamics.wheel_rim_speeds` where their bound
        |v_i| <= |(x', y')| + l |theta'| (|d_i| = 1) could exceed the limit.
        """
        bounds = self.bounds
        ratio = max(float(np.max(np.abs(d) / b)) for d, b in zip((vel, acc, jerk), bounds))
        if ratio > LIMIT_MARGIN:
            return ratio  # over a limit already: the wheels need not be looked at
        rim_bound = np.hypot(vel[:, 0], vel[:, 1]) + self.robot.l * np.abs(vel[:, 2])
        for k in np.flatnonzero(rim_bound > LIMIT_MARGIN * self.rim_speed_mps):
            rim = float(np.max(np.abs(wheel_rim_speeds(float(theta[k]), vel[k], self.robot))))
            ratio = max(ratio, rim / self.rim_speed_mps)
        return ratio


def shortest_duration(usage: Callable[[float], float], start_s: float = 0.05) -> float:
    """The shortest duration T (to 0.2 %) with usage(T) <= `LIMIT_MARGIN`: doubling from `start_s`, then bisection.

    Few evaluations on purpose: the trajectory node plans in its callback, and a long stall of its previews
    makes the controller extrapolate the last one (its error grows like jerk dt^3 / 6).

    A start state near a limit can make every continuation exceed it a little (the polynomial's
    acceleration and jerk overshoot the initial ones by a factor that does not shrink with T); then
    the scanned duration with the least usage is returned, as long as it is below `MAX_OVERSHOOT`.

    Raises
    ------
    GoalError
        When no duration up to `MAX_DURATION_S` keeps usage below `MAX_OVERSHOOT`.
    """
    lo, hi = 0.0, start_s
    best = (math.inf, hi)
    while (used := usage(hi)) > LIMIT_MARGIN:
        best = min(best, (used, hi))
        lo, hi = hi, hi * 2.0
        if hi > MAX_DURATION_S:
            if best[0] > MAX_OVERSHOOT:
                raise GoalError(f"no motion within {MAX_OVERSHOOT:g} times the limits lasts less than "
                                f"{MAX_DURATION_S:g} s")
            return best[1]
    for _ in range(40):
        if hi - lo <= 2e-3 * hi:
            break
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if usage(mid) <= LIMIT_MARGIN else (mid, hi)
    return hi


# d^k/dtau^k of tau^n at tau = 1: n! / (n - k)!, rows k = 0..3, columns n = 4..7 (the free coefficients)
_END = np.array([[math.perm(n, k) for n in range(4, 8)] for k in range(4)], dtype=float)


def _checked_duration(duration_s: float) -> float:
    if not (math.isfinite(duration_s) and duration_s > 0.0):
        raise GoalError(f"duration_s must be positive and finite, got {duration_s!r}")
    return float(duration_s)


def _head(state: np.ndarray, T: float) -> np.ndarray:
    """c_0..c_3 (4, 3) in tau = t / T of a motion from `state` (p, v, a, j): p, v T, a T^2 / 2, j T^3 / 6."""
    return state * (np.array([1.0, T, T * T / 2.0, T**3 / 6.0])[:, None])


def _derivative_coefficients(c: np.ndarray) -> list[np.ndarray]:
    """Coefficients (8, 3) in tau of p and of its tau-derivatives 1..3 (ascending powers, zero-padded)."""
    out = [c]
    for _ in range(3):
        prev = out[-1]
        out.append(np.vstack((prev[1:] * np.arange(1, len(prev))[:, None], np.zeros((1, prev.shape[1])))))
    return out


class PolynomialMotion:
    """Per axis the degree-7 polynomial from a state (p, v, a, j) to rest at `goal` over `duration_s`.

    With tau = t / T: c_0 = p, c_1 = v T, c_2 = a T^2 / 2, c_3 = j T^3 / 6, and
    c_4..c_7 solve p(1) = goal, p'(1) = p''(1) = p'''(1) = 0.

    Parameters
    ----------
    state
        (4, 3): position, velocity, acceleration, jerk of (x, y, theta) at the start.
    goal
        (x, y, theta) reached at rest at t = duration_s.
    duration_s
        T > 0.
    """

    def __init__(self, state: np.ndarray, goal: np.ndarray, duration_s: float) -> None:
        s = checked_array(state, (4, 3), "start state (p, v, a, j)", GoalError)
        g = checked_array(goal, (3,), "goal (x, y, theta)", GoalError)
        T = _checked_duration(duration_s)
        head = _head(s, T)
        # residuals at tau = 1 of the known part: goal - p_head(1), then -p_head^(k)(1)
        known = np.array([[math.perm(n, k) for n in range(4)] for k in range(4)], dtype=float) @ head
        rhs = -known
        rhs[0] += g
        self._use(np.vstack((head, np.linalg.solve(_END, rhs))), T)
        self.goal = g

    def _use(self, coefficients: np.ndarray, duration_s: float) -> None:
        """Take the coefficients (8, 3) in tau of p over `duration_s`."""
        T = duration_s
        self.coefficients, self.duration_s = coefficients, T
        self._derivs = _derivative_coefficients(coefficients)
        self._scales = (1.0, 1.0 / T, 1.0 / T**2, 1.0 / T**3)

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """(4, n, 3): position, velocity, acceleration, jerk at local times t (clipped to [0, T]: rest after)."""
        tau = np.clip(np.asarray(t, dtype=float) / self.duration_s, 0.0, 1.0)
        powers = tau[:, None] ** np.arange(8)  # (n, 8)
        return np.stack([powers @ c * scale for c, scale in zip(self._derivs, self._scales)])

    @classmethod
    def within(cls, state: np.ndarray, goal: np.ndarray, limits: MotionLimits) -> PolynomialMotion | None:
        """The shortest such motion within `limits` (checked on `GRID_POINTS` samples); None if already there at rest.

        Raises
        ------
        GoalError
            Non-finite input, or no duration up to `MAX_DURATION_S` keeps the limits.
        """
        s = checked_array(state, (4, 3), "start state (p, v, a, j)", GoalError)
        g = checked_array(goal, (3,), "goal (x, y, theta)", GoalError)
        if not s[1:].any() and np.array_equal(s[0], g):
            return None
        tau = np.linspace(0.0, 1.0, GRID_POINTS)

        def usage(T: float) -> float:
            motion = cls(s, g, T)
            p, v, a, j = motion.evaluate(tau * T)
            return limits.usage(p[:, 2], v, a, j)

        return cls(s, g, shortest_duration(usage))


# d^k/dtau^k of tau^n at tau = 1 for k = 1..3, n = 4..6 (the braking motion's free coefficients)
_BRAKE_END = np.array([[math.perm(n, k) for n in range(4, 7)] for k in range(1, 4)], dtype=float)


class BrakingMotion(PolynomialMotion):
    """Per axis the degree-6 polynomial from a state (p, v, a, j) to rest wherever that brings it: a stop.

    c_0..c_3 as in `PolynomialMotion`; c_4..c_6 solve p'(1) = p''(1) = p'''(1) = 0, and the rest position
    ``goal`` = p(1) follows. From (p, v, 0, 0) the velocity is v (1 - q(tau)), q the quintic smoothstep
    10 tau^3 - 15 tau^4 + 6 tau^5, so the stop takes v T / 2 of travel. C^3 at the switch and at rest after T.

    Parameters
    ----------
    state
        (4, 3): position, velocity, acceleration, jerk of (x, y, theta) when the stop starts.
    duration_s
        T > 0.
    """

    def __init__(self, state: np.ndarray, duration_s: float) -> None:
        s = checked_array(state, (4, 3), "start state (p, v, a, j)", GoalError)
        T = _checked_duration(duration_s)
        head = _head(s, T)
        known = np.array([[math.perm(n, k) for n in range(4)] for k in range(1, 4)], dtype=float) @ head
        self._use(np.vstack((head, np.linalg.solve(_BRAKE_END, -known), np.zeros((1, 3)))), T)
        self.goal = self.coefficients.sum(axis=0)  # p(tau = 1)

    @classmethod
    def stopping(cls, state: np.ndarray, limits: MotionLimits) -> BrakingMotion | None:
        """The shortest stop within `limits` (checked on `GRID_POINTS` samples); None if already at rest (`AT_REST`).

        Raises
        ------
        GoalError
            Non-finite state, or no duration up to `MAX_DURATION_S` keeps the limits.
        """
        s = checked_array(state, (4, 3), "start state (p, v, a, j)", GoalError)
        if np.abs(s[1:]).max() <= AT_REST:
            return None
        tau = np.linspace(0.0, 1.0, GRID_POINTS)

        def usage(T: float) -> float:
            p, v, a, j = cls(s, T).evaluate(tau * T)
            return limits.usage(p[:, 2], v, a, j)

        return cls(s, shortest_duration(usage))
