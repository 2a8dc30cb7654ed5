"""C^3 reference trajectories (x_d, y_d, theta_d) and the N-step preview the MPCs track (eqs. 50-54).

The functional controllability of Section IV (Theorem 1, Remark 1) asks for
references whose third derivative is continuous: every reference here is C^3
in time *including* its start and end, so the robot can start at rest and
follow it. Positions, velocities, accelerations and jerks are analytic (chain
rule of Faa di Bruno on a smooth curve and a smooth time law, `reference.time_law`),
never numerical differences.

References (`REFERENCES`; docs/theory.md, "The reference scenarios"):

* ``paper-circle``: the circle of Figs. 4-6, radius 0.5 m, period 10 s,
  theta_d = 0, starting and ending at rest at the origin (with ``ramp_in=False``
  at full speed from t = 0, as the paper ran it: not C^3 at its start);
* ``lemniscate``: a figure-eight (lemniscate of Gerono) 1 m wide, period
  20 s, theta_d along the path;
* ``point-to-point``: rest-to-rest moves through waypoints (x, y, theta) with
  the septic time law ``septic(tau)``.

A scenario (reference, controller model mismatch, odometry noise) is
`robotino_geom_mpc.scenarios`' business: ``robustness`` tracks ``paper-circle``.
"""

from __future__ import annotations

import inspect
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np

from robotino_geom_mpc.arrays import checked_array
from .time_law import (
    TrajectoryError,
    _Backend,
    _compose,
    _ramp_deficit,
    _RampedPhase,
    _Scalar,
    _septic,
    _Vector,
    septic,
)

__all__ = [
    "REFERENCES",
    "TrajectoryError",
    "Reference",
    "CircleReference",
    "LemniscateReference",
    "PointToPointReference",
    "septic",
    "make_reference",
    "preview",
    "shift_preview",
    "preview_at",
    "whole_periods",
]

# Default waypoints of point-to-point: along x, a pure rotation in place, a
# diagonal move, and back to the origin rotating on the way.
_DEFAULT_WAYPOINTS = (
    (0.5, 0.0, 0.0),
    (0.5, 0.0, 0.5 * math.pi),
    (0.0, 0.5, 0.5 * math.pi),
    (0.0, 0.0, 0.0),
)
_SEPTIC_PEAK_RATE = 35.0 / 16.0  # max of s'(tau), at tau = 1/2


def _array(value: object, name: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TrajectoryError(f"{name} must be numbers, got {value!r}") from None


def _positive(value: object, name: str) -> float:
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise TrajectoryError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out) or out <= 0.0:
        raise TrajectoryError(f"{name} must be a positive finite number, got {value!r}")
    return out


# --------------------------------------------------------------------------- references


class Reference(ABC):
    """A C^3 reference (x_d, y_d, theta_d)(t) over [0, duration_s]; holds its end pose outside.

    Attributes
    ----------
    name
        The scenario name.
    duration_s
        Length of the run [s].
    """

    name: str
    duration_s: float

    @abstractmethod
    def _kernel(self, t, xp: _Backend, derivatives: bool) -> list:  # noqa: ANN001
        """[pos] or [pos, vel, acc, jerk] at t (float or 1-D array), each an (x, y, theta) triple."""

    def _evaluate(self, t: object, derivatives: bool) -> list[np.ndarray]:
        if isinstance(t, (float, int)) and math.isfinite(t):
            return [np.array(v, dtype=float) for v in self._kernel(float(t), _Scalar, derivatives)]
        arr = np.asarray(t, dtype=float)
        if arr.ndim > 1:
            raise TrajectoryError(f"t must be a scalar or a 1-D array, got shape {arr.shape}")
        if not np.isfinite(arr).all():
            raise TrajectoryError("t must be finite")
        if arr.ndim == 0:
            return [np.array(v, dtype=float) for v in self._kernel(float(arr), _Scalar, derivatives)]
        values = self._kernel(arr, _Vector, derivatives)
        return [np.column_stack(np.broadcast_arrays(*value)) for value in values]

    def sample(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration and jerk of (x, y, theta) at time(s) t.

        Returns
        -------
        (pos, vel, acc, jerk), each (len(t), 3) for an array t or (3,) for a scalar.
        """
        return tuple(self._evaluate(t, True))  # type: ignore[return-value]

    def position(self, t: float | np.ndarray) -> np.ndarray:
        """Position (x, y, theta) only: (len(t), 3) or (3,)."""
        return self._evaluate(t, False)[0]


class _SteppedPhase:
    """Phase phi(t) advancing by `total` [rad] at its full `rate` from t = 0 (no ramp-in), ramped out as `_RampedPhase`.

    phi'(t) = rate h((D - t) / T_r) on [0, D], h the septic smoothstep, so
    phi(t) = rate (t - T_r E((D - t) / T_r)) with E the ramp deficit and
    D = total / rate + T_r / 2; phi' steps from 0 to `rate` at t = 0 (rest before).
    """

    def __init__(self, rate: float, ramp_s: float, total: float, name: str) -> None:
        if total / rate < 0.5 * ramp_s:
            raise TrajectoryError(f"{name}: ramp_s = {ramp_s:g} s is too long for the run "
                                  f"(at most {2 * total / rate:g} s)")
        self.rate, self.ramp_s = rate, ramp_s
        self.duration_s = total / rate + 0.5 * ramp_s

    def evaluate(self, t, xp: _Backend, derivatives: bool):  # noqa: ANN001, ANN201
        """(phi,) or (phi and its first three derivatives) at t."""
        started = 1.0 * (t >= 0.0)
        t = xp.clip(t, 0.0, self.duration_s)
        tr, rate = self.ramp_s, self.rate
        tau_out = (self.duration_s - t) / tr
        phi = rate * (t - tr * _ramp_deficit(tau_out, xp))
        if not derivatives:
            return (phi,)
        h = _septic(tau_out, xp)
        return (phi, started * rate * h[0], -started * rate / tr * h[1], started * rate / tr**2 * h[2])


class CircleReference(Reference):
    """The paper's circle (Section V, Figs. 4-6) with theta_d = 0, starting at rest at the origin.

    (x, y) = radius (sin phi, 1 - cos phi): the centre is (0, radius), the
    robot starts at the origin heading along +x and turns counter-clockwise.
    The angular rate phi' ramps in over `ramp_s` with a septic smoothstep to
    2 pi / period_s and ramps out symmetrically; the total phase is
    laps * 2 pi, so the run ends at rest at the origin after
    duration_s = laps * period_s + ramp_s. The laps count the whole run,
    ramps included.

    The ramp's peak tangential acceleration is radius (2 pi / period_s)
    (35/16) / ramp_s (0.34 m/s^2 for the defaults), next to the centripetal
    radius (2 pi / period_s)^2 (0.2 m/s^2).

    ``ramp_in=False`` is the paper's start: phi' = 2 pi / period_s from t = 0,
    so the reference's velocity jumps from rest to radius 2 pi / period_s
    (0.31 m/s) at the start (not C^3 there); the ramp-out is kept and the run
    lasts laps * period_s + ramp_s / 2.
    """

    def __init__(
        self,
        radius_m: float = 0.5,
        period_s: float = 10.0,
        laps: float = 2.0,
        ramp_s: float = 2.0,
        ramp_in: bool = True,
    ) -> None:
        self.name = "paper-circle"
        self.radius_m = _positive(radius_m, "radius_m")
        self.period_s = _positive(period_s, "period_s")
        laps = _positive(laps, "laps")
        phase = _RampedPhase if ramp_in else _SteppedPhase
        self._phase = phase(2.0 * math.pi / self.period_s, _positive(ramp_s, "ramp_s"), 2.0 * math.pi * laps, self.name)
        self.duration_s = self._phase.duration_s

    def _kernel(self, t, xp: _Backend, derivatives: bool) -> list:  # noqa: ANN001
        phase = self._phase.evaluate(t, xp, derivatives)
        r = self.radius_m
        rs, rc = r * xp.sin(phase[0]), r * xp.cos(phase[0])
        pos = (rs, r - rc, 0.0)
        if not derivatives:
            return [pos]
        return _compose([pos, (rc, rs, 0.0), (-rs, rc, 0.0), (-rc, -rs, 0.0)], phase)


class LemniscateReference(Reference):
    """Figure-eight (lemniscate of Gerono) with theta_d the direction of travel.

    Curve: (a sin s, b sin 2s), a = width_m / 2, b = height_m / 2, translated
    so that the start s0 = pi/4 (the top of the right lobe, where the tangent
    points along +x) is the origin; hence theta_d(0) = 0. The parameter s runs
    s0 + phi(t) with phi ramped in and out as in `CircleReference`: one lap of
    s takes period_s at full speed, duration_s = laps * period_s + ramp_s, and
    the run ends at rest at the origin.

    theta_d = psi(s), the tangent angle atan2(y_s, x_s) of the curve, which is
    defined at rest too (the limit direction of the velocity) and is a smooth
    function of s. The tangent never points along +y (where x_s = 0,
    y_s = -2b), so psi is taken continuously in (-3 pi/2, pi/2): no unwrapping
    by history, and theta_d is C^3 in time. Its derivatives with respect to s
    follow from psi_s = (x_s y_ss - y_s x_ss) / (x_s^2 + y_s^2).
    """

    _S0 = 0.25 * math.pi

    def __init__(
        self,
        width_m: float = 1.0,
        height_m: float = 0.5,
        period_s: float = 20.0,
        laps: float = 1.0,
        ramp_s: float = 2.0,
    ) -> None:
        self.name = "lemniscate"
        self.a = 0.5 * _positive(width_m, "width_m")
        self.b = 0.5 * _positive(height_m, "height_m")
        self.period_s = _positive(period_s, "period_s")
        laps = _positive(laps, "laps")
        self._phase = _RampedPhase(
            2.0 * math.pi / self.period_s, _positive(ramp_s, "ramp_s"), 2.0 * math.pi * laps, self.name
        )
        self.duration_s = self._phase.duration_s
        self._x0 = self.a * math.sin(self._S0)
        self._y0 = self.b * math.sin(2.0 * self._S0)

    def _kernel(self, t, xp: _Backend, derivatives: bool) -> list:  # noqa: ANN001
        phase = self._phase.evaluate(t, xp, derivatives)
        s = self._S0 + phase[0]
        a, b = self.a, self.b
        sn, cs, sn2, cs2 = xp.sin(s), xp.cos(s), xp.sin(2.0 * s), xp.cos(2.0 * s)
        x1, y1 = a * cs, 2.0 * b * cs2
        pos = (a * sn - self._x0, b * sn2 - self._y0, xp.heading(xp.atan2(y1, x1)))
        if not derivatives:
            return [pos]
        x2, x3, x4 = -a * sn, -x1, a * sn
        y2, y3, y4 = -4.0 * b * sn2, -4.0 * y1, 16.0 * b * sn2
        num = x1 * y2 - y1 * x2
        num1 = x1 * y3 - y1 * x3
        num2 = x2 * y3 + x1 * y4 - y2 * x3 - y1 * x4
        den = x1 * x1 + y1 * y1
        den1 = 2.0 * (x1 * x2 + y1 * y2)
        den2 = 2.0 * (x2 * x2 + x1 * x3 + y2 * y2 + y1 * y3)
        quotient = num1 * den - num * den1
        psi2 = quotient / (den * den)
        psi3 = (num2 * den - num * den2) / (den * den) - 2.0 * den1 * quotient / (den * den * den)
        return _compose([pos, (x1, y1, num / den), (x2, y2, psi2), (x3, y3, psi3)], phase)


class PointToPointReference(Reference):
    """Rest-to-rest moves through waypoints (x, y, theta), each with the septic time law.

    Segment k moves from pose p_k to p_{k+1} as p_k + (p_{k+1} - p_k) s(tau),
    tau = (t - t_k) / T_k, s = `septic` (zero velocity, acceleration and jerk
    at both ends, so the joints are C^3); each move is followed by a dwell of
    `dwell_s` at rest. theta of a waypoint is absolute and is not wrapped
    (theta = 2 pi asks for a full turn).

    Segment durations: `segment_s` (one value, or one per waypoint) or, by
    default, the time that keeps the peak speed (35/16 times the mean) within
    `max_speed_m_s` and `max_rate_rad_s`, at least `min_segment_s`.

    Attributes
    ----------
    waypoints
        (m, 3) target poses.
    arrival_times_s
        (m,) time each move ends (at rest at its waypoint).
    """

    def __init__(
        self,
        waypoints: Sequence[Sequence[float]] | np.ndarray | None = None,
        start: Sequence[float] = (0.0, 0.0, 0.0),
        segment_s: float | Sequence[float] | None = None,
        max_speed_m_s: float = 0.25,
        max_rate_rad_s: float = 0.8,
        min_segment_s: float = 1.0,
        dwell_s: float = 1.0,
    ) -> None:
        self.name = "point-to-point"
        wp = _array(_DEFAULT_WAYPOINTS if waypoints is None else waypoints, "waypoints")
        if wp.ndim != 2 or wp.shape[1] != 3 or wp.shape[0] == 0:
            raise TrajectoryError(
                f"waypoints must be a non-empty list of (x, y, theta), got shape {wp.shape}"
            )
        if not np.isfinite(wp).all():
            raise TrajectoryError("waypoints must be finite")
        p_start = checked_array(start, (3,), "start (x, y, theta)", TrajectoryError)
        dwell_value = _array(dwell_s, "dwell_s")
        if dwell_value.shape != () or not math.isfinite(dwell_value) or dwell_value < 0.0:
            raise TrajectoryError(f"dwell_s must be >= 0, got {dwell_s!r}")
        dwell = float(dwell_value)
        poses = np.vstack((p_start, wp))
        delta = np.diff(poses, axis=0)
        m = len(wp)
        if segment_s is None:
            v_max = _positive(max_speed_m_s, "max_speed_m_s")
            w_max = _positive(max_rate_rad_s, "max_rate_rad_s")
            durations = np.maximum.reduce(
                [
                    np.full(m, _positive(min_segment_s, "min_segment_s")),
                    _SEPTIC_PEAK_RATE * np.hypot(delta[:, 0], delta[:, 1]) / v_max,
                    _SEPTIC_PEAK_RATE * np.abs(delta[:, 2]) / w_max,
                ]
            )
        else:
            values = np.atleast_1d(_array(segment_s, "segment_s"))
            if values.ndim != 1 or len(values) not in (1, m):
                raise TrajectoryError(f"segment_s must be one value or {m} values, got {segment_s!r}")
            durations = np.array([_positive(v, "segment_s") for v in np.broadcast_to(values, (m,))])
        # Each move is followed by a dwell (a segment with zero displacement).
        segments = []
        for k in range(m):
            segments.append((durations[k], poses[k], delta[k]))
            if dwell > 0.0:
                segments.append((dwell, wp[k], np.zeros(3)))
        durations_all = np.array([seg[0] for seg in segments])
        t0 = np.concatenate(([0.0], np.cumsum(durations_all)[:-1]))
        # Columns (t0, T, p0 x/y/theta, delta x/y/theta): numpy for the vector
        # backend, Python lists for the scalar one.
        table = np.column_stack(
            (t0, durations_all, [seg[1] for seg in segments], [seg[2] for seg in segments])
        )
        self._columns = {_Vector: tuple(table.T.copy()), _Scalar: tuple(table.T.tolist())}
        self.waypoints = wp
        self.start = p_start
        self.arrival_times_s = t0[:: 2 if dwell > 0.0 else 1] + durations
        self.duration_s = float(t0[-1] + durations_all[-1])

    def _kernel(self, t, xp: _Backend, derivatives: bool) -> list:  # noqa: ANN001
        columns = self._columns[xp]
        k = xp.segment(columns[0], t)
        t0, T, p0 = columns[0][k], columns[1][k], columns[2:5]
        delta = [d[k] for d in columns[5:8]]
        s = _septic((t - t0) / T, xp)
        pos = [p[k] + d * s[0] for p, d in zip(p0, delta)]
        if not derivatives:
            return [pos]
        rates = (s[1] / T, s[2] / (T * T), s[3] / (T * T * T))
        return [pos] + [[d * rate for d in delta] for rate in rates]


# --------------------------------------------------------------------------- factory, preview

_FACTORIES = {
    "paper-circle": CircleReference,
    "lemniscate": LemniscateReference,
    "point-to-point": PointToPointReference,
}
REFERENCES: tuple[str, ...] = tuple(_FACTORIES)


def make_reference(name: str, **options: object) -> Reference:
    """A reference by name, with options.

    Parameters
    ----------
    name
        One of `REFERENCES` (a scenario of `robotino_geom_mpc.scenarios` names its reference).
    **options
        Keyword arguments of the reference's class (`CircleReference`,
        `LemniscateReference`, `PointToPointReference`).

    Raises
    ------
    TrajectoryError
        Unknown reference or option, or an invalid option value.
    """
    if name not in _FACTORIES:
        raise TrajectoryError(f"unknown reference {name!r}; valid: {', '.join(REFERENCES)}")
    cls = _FACTORIES[name]
    allowed = tuple(inspect.signature(cls).parameters)
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise TrajectoryError(
            f"unknown option(s) {', '.join(unknown)} for {name}; valid: {', '.join(allowed)}"
        )
    return cls(**options)


def preview(reference: Reference, t: float, period_s: float, horizon: int) -> np.ndarray:
    """Reference positions at t + Ts, ..., t + N Ts, the x_d(k + j) of eq. (54).

    After the end of the reference the final pose is held.

    Returns
    -------
    (horizon, 3) array of (x, y, theta).
    """
    if not isinstance(reference, Reference):
        raise TrajectoryError(f"reference must be a Reference, got {type(reference).__name__}")
    if not math.isfinite(t):
        raise TrajectoryError(f"t must be finite, got {t!r}")
    if not period_s > 0.0 or not math.isfinite(period_s):
        raise TrajectoryError(f"period_s must be positive and finite, got {period_s!r}")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise TrajectoryError(f"horizon must be a positive integer, got {horizon!r}")
    t, period_s = float(t), float(period_s)
    # The scalar kernel per point beats numpy's per-call overhead for a short horizon.
    return np.array([reference._kernel(t + j * period_s, _Scalar, False)[0] for j in range(1, horizon + 1)])


def shift_preview(positions: np.ndarray, velocities: np.ndarray, accelerations: np.ndarray, dt_s: float) -> np.ndarray:
    """Preview points moved by `dt_s` in time: x_d(t_j + dt) ~ x_d(t_j) + v_d(t_j) dt + a_d(t_j) dt^2 / 2.

    In realtime the freshest preview is stamped t_p on the trajectory node's
    timer and the odometry t_k on the plant's; the MPC needs x_d(k + j) =
    x_d(t_k + j Ts) (eq. 54), so every point moves by dt = t_k - t_p. The
    second-order Taylor step errs by at most max|jerk| |dt|^3 / 6 per point
    (about 2e-7 m for 1 m/s^3 and dt = 10 ms). Arrays are (points, 3) of
    (x, y, theta) and their first and second derivatives.
    """
    return positions + dt_s * velocities + (0.5 * dt_s * dt_s) * accelerations


def preview_at(stamp_ns: int, preview_stamp_ns: int, positions: np.ndarray, velocities: np.ndarray,
               accelerations: np.ndarray, period_ns: int, points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The `points` reference points at `stamp_ns` + j Ts, j = 0..points - 1, from a preview stamped `preview_stamp_ns`.

    A preview holds the reference at its stamp + j Ts (eq. 54's x_d(k + j) with derivatives, rows j of the
    arrays); one longer than `points` (a trajectory node that publishes every few periods) covers the odometries
    after its stamp: the whole periods m elapsed since the stamp are taken from its rows m.. (as many as it has
    beyond `points`), the remainder dt = t_k - t_p - m Ts by `shift_preview` (second order; the velocities by
    the accelerations). A preview of exactly `points` rows, or one newer than the stamp, is moved by dt alone.

    Returns
    -------
    positions, velocities, accelerations, each (points, 3).
    """
    gap = stamp_ns - preview_stamp_ns
    m = whole_periods(gap, period_ns, len(positions) - points)
    rows = slice(m, m + points)
    dt = (gap - m * period_ns) * 1e-9
    velocity, acceleration = velocities[rows], accelerations[rows]
    return shift_preview(positions[rows], velocity, acceleration, dt), velocity + dt * acceleration, acceleration


def whole_periods(gap_ns: int, period_ns: int, most: int) -> int:
    """The whole periods m in `gap_ns` that a preview's later rows cover: 0 <= m <= `most` (its rows to spare)."""
    return min(max(gap_ns // period_ns, 0), most)
