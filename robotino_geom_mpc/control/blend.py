"""Bumpless (re)start of the tracking: a C^3 offset that takes the reference from the measured state to itself.

When control (re)starts (first tick, data back after a watchdog stop, a
reference that jumped, rebuilt controller) the controller is reset
(u(k-1) = 0) and the robot is wherever it is, moving however it moves. Fed
the bare reference, the MPCs would see the whole difference as a tracking
error and answer with a voltage step. Instead the reference gets an offset

    o(t) = q(t) w(tau),   q(t) = dp + dv (t - t0) + da (t - t0)^2 / 2,   tau = (t - t0) / T,
    w(tau) = 1 - s(tau),  s = the septic smoothstep (`reference.trajectories.septic`), w = 0 for tau >= 1,

with dp = measured pose - reference, dv = measured velocity - reference
velocity and da = (acceleration the robot has under u(k-1)) - reference
acceleration at t0. Since w(0) = 1 and w', w'', w''' vanish at 0 and at 1,
the blended reference r + o starts at the measured pose, velocity and
acceleration, is C^3 (Remark 1: the MPCs can follow it) and meets the
reference at t0 + T with all derivatives up to the third. T is the shortest
duration (at least one control period) over which the offset's
acceleration stays within the limits (the norm of its x, y part within the
linear limit, |theta''| within the angular one), which keeps the extra
wheel currents bounded.

With tau = (t - t0) / T, o(t) = dp w + dv T (tau w) + da T^2 (tau^2 w) / 2, so
o''(t) = dp w'' / T^2 + dv (tau w)'' / T + da (tau^2 w)'' / 2: the last term
does not shrink with T. If it alone exceeds the limit (the reference's own
acceleration is above the blend's limit), the limit of that axis group is
raised to twice its maximum, so a finite T exists; `ReferenceBlend.limited`
says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import Polynomial

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.arrays import checked_array

__all__ = ["ANGULAR_LIMIT_RADPS2", "BlendEngagement", "BlendError", "LINEAR_LIMIT_MPS2", "ReferenceBlend"]

# default acceleration limits of the offset: with them the extra wheel currents stay a fraction of the nominal
LINEAR_LIMIT_MPS2 = 0.3
ANGULAR_LIMIT_RADPS2 = 1.0

# w(tau) = 1 - s(tau) and tau^k w(tau), k = 0, 1, 2, as polynomials in tau (valid on [0, 1])
_W = Polynomial([1.0, 0.0, 0.0, 0.0, -35.0, 84.0, -70.0, 20.0])
_TAU = Polynomial([0.0, 1.0])
# o(t) = dp P0 + dv T P1 + da T^2 P2 with these polynomials of tau
_P = (_W, _TAU * _W, 0.5 * _TAU * _TAU * _W)
# their second derivatives on a tau grid: o'' = dp P0'' / T^2 + dv P1'' / T + da P2''
_GRID = np.linspace(0.0, 1.0, 1025)
_P2_GRID = np.array([p.deriv(2)(_GRID) for p in _P])  # (3, grid)
# the grid misses a peak between its points by less than this fraction (polynomials of degree <= 9)
_GRID_MARGIN = 1e-3
_CANDIDATES = 1.1 ** np.arange(200)  # durations tried, in periods (up to 2e8), in chunks of
_CHUNK = 20
_BISECTIONS = 30


class BlendError(RobotinoError, ValueError):
    """Blend inputs that are not finite 3-vectors, or limits / periods that are not positive."""


def _peaks(dp: np.ndarray, dv: np.ndarray, da: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Peak |(x'', y'')| and peak |theta''| of the offsets of the durations T (shape (m,)): shape (m, 2)."""
    inv = 1.0 / T[:, None]
    c0, c1, c2 = _P2_GRID
    a0, a1 = inv * inv * c0, inv * c1  # (m, grid): o'' = a0 dp + a1 dv + c2 da, one axis at a time
    x, y, theta = (a0 * p + a1 * v + c2 * a for p, v, a in zip(dp.tolist(), dv.tolist(), da.tolist()))
    return np.column_stack((np.sqrt(np.max(x * x + y * y, axis=1)), np.max(np.abs(theta), axis=1)))


@dataclass(frozen=True)
class ReferenceBlend:
    """An engaged blend: o(t) for t >= t0 (zero after t0 + T).

    Attributes
    ----------
    t0_s
        Time at which the blend starts [s] (any time base; the node uses the odometry stamps).
    duration_s
        T [s].
    dp, dv, da
        o(t0), o'(t0), o''(t0): (x, y, theta) in m, rad and their rates.
    limits
        The acceleration limits met (linear [m/s^2], angular [rad/s^2]); above the requested ones
        where the reference's own acceleration needed more (see `limited`).
    limited
        True if a requested limit had to be raised (see the module docstring).
    """

    t0_s: float
    duration_s: float
    dp: tuple[float, float, float]
    dv: tuple[float, float, float]
    da: tuple[float, float, float]
    limits: tuple[float, float]
    limited: bool

    @classmethod
    def engage(cls, t0_s: float, dp: object, dv: object, da: object, linear_limit: float, angular_limit: float,
               period_s: float) -> ReferenceBlend:
        """The blend of the shortest duration >= `period_s` whose acceleration stays within the limits.

        Parameters
        ----------
        t0_s
            Start time [s].
        dp, dv, da
            Offset, its rate and its acceleration at t0, each (x, y, theta).
        linear_limit, angular_limit
            Bound on |(x'', y'')| of the offset [m/s^2] and on |theta''| [rad/s^2].
        period_s
            The control period: the shortest duration.

        Raises
        ------
        BlendError
            For non-finite or wrongly shaped vectors, or limits / period that are not positive and finite.
        """
        dp, dv, da = (checked_array(v, (3,), name, BlendError) for v, name in ((dp, "dp"), (dv, "dv"), (da, "da")))
        if not math.isfinite(t0_s):
            raise BlendError(f"t0_s must be finite, got {t0_s!r}")
        for name, value in (("linear_limit", linear_limit), ("angular_limit", angular_limit), ("period_s", period_s)):
            if not (math.isfinite(value) and value > 0.0):
                raise BlendError(f"{name} must be positive and finite, got {value!r}")
        # the part that does not shrink with T: da (tau^2 w)'' / 2
        floor = _peaks(np.zeros(3), np.zeros(3), da, np.ones(1))[0]
        requested = np.array((linear_limit, angular_limit))
        limits = np.where(floor > 0.5 * requested, 2.0 * floor, requested)
        bound = limits * (1.0 - _GRID_MARGIN)

        def within(T: np.ndarray) -> np.ndarray:
            return np.all(_peaks(dp, dv, da, T) <= bound, axis=1)

        # the dp and dv parts fall as 1/T^2 and 1/T: a duration within the bound exists; the shortest alone first
        # (a start at rest needs no more, a fifteenth of a chunk's cost), then a scan in chunks
        candidates = period_s * _CANDIDATES
        low, high = None, None
        if within(candidates[:1])[0]:
            high = float(candidates[0])
        else:
            for chunk in np.split(candidates, len(_CANDIDATES) // _CHUNK):
                ok = within(chunk)
                if ok.any():
                    first = int(np.argmax(ok))
                    high = float(chunk[first])
                    low = float(chunk[first - 1]) if first else low
                    break
                low = float(chunk[-1])
        if high is None:
            raise BlendError(f"no blend duration up to {period_s * _CANDIDATES[-1]:g} s meets the limits")
        if low is not None:
            for _ in range(_BISECTIONS):
                mid = 0.5 * (low + high)
                low, high = (low, mid) if within(np.array([mid]))[0] else (mid, high)
        return cls(float(t0_s), high, tuple(dp.tolist()), tuple(dv.tolist()), tuple(da.tolist()),
                   (float(limits[0]), float(limits[1])), bool(np.any(limits != requested)))

    def remaining_s(self, t_s: float) -> float:
        """Time left until the blend ends [s] (0 when over)."""
        return max(0.0, self.t0_s + self.duration_s - t_s)

    def derivatives(self, t_s: object, order: int = 0) -> np.ndarray:
        """The `order`-th time derivative of o at the times `t_s` (shape (n,)), shape (n, 3); order 0..3.

        Before t0 the offset is held at its start values (the polynomial is not extended), after t0 + T it is 0.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        T = self.duration_s
        tau = np.clip((t - self.t0_s) / T, 0.0, 1.0)
        scales = (1.0, T, T * T)
        out = np.zeros((len(t), 3))
        for poly, scale, coef in zip(_P, scales, (self.dp, self.dv, self.da)):
            values = poly.deriv(order)(tau) * (scale / T**order) if order else poly(tau) * scale
            out += np.outer(values, coef)
        out[tau >= 1.0] = 0.0
        return out

    def offset(self, t_s: object) -> np.ndarray:
        """o(t) at the times `t_s`, shape (n, 3)."""
        return self.derivatives(t_s, 0)


class BlendEngagement:
    """The node's bumpless (re)start: when to engage a `control.blend.ReferenceBlend`, and the offsets of each tick.

    Parameters
    ----------
    period_s, horizon
        Ts and N (the preview points 1..N lie at t_k + j Ts).
    """

    def __init__(self, period_s: float, horizon: int) -> None:
        self.period_s = period_s
        self.preview_times = period_s * np.arange(1, horizon + 1)
        self.reason: str | None = "start"  # why the next tick engages (None: it does not)
        self.jump_ns: int | None = None  # stamp of a preview whose reference jumped (engage at the tick using it)
        self.blend: ReferenceBlend | None = None
        self.t0_ns = 0
        self.engagements = 0

    def request(self, reason: str) -> None:
        """Engage at the next tick."""
        self.reason = reason
        self.blend = None

    def due(self, preview_stamp_ns: int) -> str | None:
        """The reason to engage at a tick using the preview of `preview_stamp_ns`, or None."""
        if self.jump_ns is not None and preview_stamp_ns >= self.jump_ns:
            self.jump_ns = None
            return self.reason or "reference_jump"
        return self.reason

    def engage(self, stamp_ns: int, X: np.ndarray, position: np.ndarray, velocity: np.ndarray,
               acceleration: np.ndarray, linear_limit: float, angular_limit: float) -> ReferenceBlend:
        """Engage the blend from the measured state X (eq. 2) to the reference (position, velocity, acceleration).

        dp = measured pose - reference, dv = measured velocity - reference velocity, da = - reference
        acceleration (the controller is reset with it: u(k-1) = 0). An all-zero offset (the robot exactly
        on a reference at rest, as in the nominal start) leaves no blend.
        """
        dp = X[0::2] - position
        dv = X[1::2] - velocity
        blend = ReferenceBlend.engage(0.0, dp, dv, -acceleration, linear_limit, angular_limit, self.period_s)
        self.reason, self.t0_ns, self.engagements = None, stamp_ns, self.engagements + 1
        self.blend = None if not (dp.any() or dv.any() or acceleration.any()) else blend
        return blend

    def offsets(self, stamp_ns: int) -> np.ndarray | None:
        """The offsets o(t_k + j Ts), j = 1..N, of the tick `stamp_ns` (shape (N, 3)), or None (no blend)."""
        if self.blend is None:
            return None
        t = (stamp_ns - self.t0_ns) * 1e-9
        if t >= self.blend.duration_s:
            self.blend = None
            return None
        return self.blend.offset(t + self.preview_times)

    def remaining_s(self, stamp_ns: int) -> float:
        """Time left of the blend at `stamp_ns` [s]."""
        return 0.0 if self.blend is None else self.blend.remaining_s((stamp_ns - self.t0_ns) * 1e-9)
