"""Pose estimate from odometry: a per-axis complementary filter (steady-state Kalman form) ahead of the MPCs.

The closed-form MPC (eq. 56) acts on the measured position with a gain of
about -1100 s^-2, so white pose noise of 1 mm reaches the commanded
acceleration as ~1 m/s^2 of noise (wheel currents of several amperes). The
body-frame twist of the odometry is far less noisy than its pose (on the
Robotino the pose is the integral of the wheel speeds; a pose fix from another
source jumps). The filter predicts each position over the period with the
measured velocity and corrects it towards the measured pose with a small gain,
so the MPCs see a position with the pose's low-frequency content and the
velocity's high-frequency content.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.params.specs import TWIST_MODELS

__all__ = ["TWIST_MODELS", "EstimatorError", "OdometryFilter", "OdometryFilterBatch", "filter_gain", "noise_std_ratio"]

_TWO_PI = 2.0 * math.pi

class EstimatorError(RobotinoError, ValueError):
    """A filter setting or measurement out of range or not finite, named in the message."""


def filter_gain(period_s: float, time_constant_s: float) -> float:
    """Correction gain L = 1 - exp(-Ts / tau) of the complementary filter (0 < L <= 1; tau = 0 gives 1).

    Parameters
    ----------
    period_s
        Sampling period Ts [s], > 0.
    time_constant_s
        Time constant tau [s] with which the estimate converges to the measured pose, >= 0.

    Returns
    -------
    float
        The exact discretisation of the continuous correction x_hat' = v + (z - x_hat) / tau.

    Raises
    ------
    EstimatorError
        For a non-finite or out-of-range argument (named in the message).
    """
    if not (math.isfinite(period_s) and period_s > 0.0):
        raise EstimatorError(f"period_s must be finite and > 0, got {period_s!r}")
    if not (math.isfinite(time_constant_s) and time_constant_s >= 0.0):
        raise EstimatorError(f"time_constant_s must be finite and >= 0, got {time_constant_s!r}")
    return 1.0 if time_constant_s == 0.0 else -math.expm1(-period_s / time_constant_s)


def noise_std_ratio(gain: float) -> float:
    """Steady-state std of the estimate's error over the std of white pose noise, sqrt(L / (2 - L)).

    Notes
    -----
    With an exact prediction the error obeys e(k) = (1 - L) e(k-1) + L n(k)
    for white measurement noise n of variance s^2, hence
    var e = L^2 s^2 / (1 - (1 - L)^2) = L s^2 / (2 - L).
    """
    if not (math.isfinite(gain) and 0.0 < gain <= 1.0):
        raise EstimatorError(f"gain must be in (0, 1], got {gain!r}")
    return math.sqrt(gain / (2.0 - gain))


class OdometryFilter:
    """Per-axis complementary filter of the odometry pose (x, y, theta), predicted with the measured velocity.

    Parameters
    ----------
    period_s
        Sampling period Ts [s] (the control period).
    time_constant_s
        tau [s] > 0: the estimate follows the measured pose through a first-order
        lag of this time constant, while the velocity carries it in between.
    twist
        How the measured velocity was obtained (`TWIST_MODELS`): ``instantaneous``
        (the trapezoid predictor) or ``period_mean`` (the dead-reckoning predictor).

    Notes
    -----
    Per axis a, with the measured position z(k) and velocity v(k) (the states
    of eq. 2), taken dt(k) after the previous measurement (Ts unless told):

        predict  p^-(k) = p(k-1) + Delta p(k),
        correct  p(k)   = p^-(k) + L(dt(k)) wrap(z(k) - p^-(k)),   L(dt) = 1 - exp(-dt / tau).

    For an instantaneous twist the advance is the trapezoid

        Delta p(k) = dt(k) (v(k-1) + v(k)) / 2.

    For a period-mean twist (body twist (v_x, v_y, omega) from the encoder
    counts over dt, rotated into the odom frame with the measured heading
    theta(k) at the interval's end, eq. 2) the advance is the one that built
    the measured pose, the SE(2) exponential of the constant body twist
    (`robotino_geom_mpc.model.encoders.integrate_pose`), written in the odom frame:
    with a = omega(k) dt(k), s = sin(a) / a, c = (1 - cos a) / a,

        Delta x(k)     = dt(k) (s x'(k) + c y'(k)),
        Delta y(k)     = dt(k) (s y'(k) - c x'(k)),     (= dt R(-a/2) sinc(a/2) v: the mean direction
        Delta theta(k) = dt(k) theta'(k),                  lies half a turn a behind theta(k))

    i.e. dt(k) v(k) when the robot does not turn. The prediction then equals
    the measured pose's own increment, so the correction sees only the pose
    noise and the filter adds no lag; the trapezoid would instead mix in
    v(k-1), half a period older, and lag the measured pose by about
    Ts^2 |p''| (1 - L) / (2 L) ~ tau Ts |p''| / 2 (0.49 mm on paper-circle).

    With the true interval a lost measurement (dt = 2 Ts), a late one or a
    repeated one (dt ~ 0: no motion predicted, L ~ 0) leaves the estimate on
    the track; assuming Ts instead puts it v Ts behind or ahead, an error the
    MPC's position gain turns into volts and the filter removes only with tau.

    The trapezoid integrates an instantaneous velocity exactly for a constant
    acceleration, i.e. for the ZOH model of eq. (49) with k_a = 0, and with a
    local error Ts^3 |jerk| / 12 otherwise. Neither predictor needs a
    model, so a wrong mass, inertia or friction in the controller does not bias
    it (a prediction with the commanded u and eq. 49 carries the model error
    into the estimate: 0.20 mm RMS tracking error in the noise-free robustness
    scenario against 0.04 mm with the trapezoid). This is the steady-state
    Kalman filter of the random-walk model p(k) = p(k-1) + Ts v_mean + w(k),
    z(k) = p(k) + n(k) with var w / var n = L^2 / (1 - L): tau sets how much
    the velocity is trusted over the pose. With white pose noise the
    estimate's error has std `noise_std_ratio(L)` times the noise's (0.10 for
    tau = 0.5 s, Ts = 10 ms); a bias b of the measured velocity becomes a
    position bias b Ts (1 - L) / L ~ b tau, which keeps tau short.

    wrap() maps the heading innovation into [-pi, pi]: a measured angle that
    jumps by 2 pi (an odometry theta wrapped to (-pi, pi]) leaves the estimate
    on its continuous branch. The first measurement after construction or
    `reset` initialises the estimate (its noise then decays with tau), unless
    `start_at` gave a known start pose.
    """

    def __init__(self, period_s: float, time_constant_s: float, twist: str = "instantaneous") -> None:
        if not (math.isfinite(time_constant_s) and time_constant_s > 0.0):
            raise EstimatorError(f"time_constant_s must be finite and > 0, got {time_constant_s!r}")
        if twist not in TWIST_MODELS:
            raise EstimatorError(f"twist must be one of {', '.join(TWIST_MODELS)}, got {twist!r}")
        self.period_s = float(period_s)
        self.time_constant_s = float(time_constant_s)
        self.twist = twist
        self._period_mean = twist == "period_mean"
        self.gain = filter_gain(self.period_s, self.time_constant_s)
        self._half_period = 0.5 * self.period_s
        self.reset()

    def reset(self) -> None:
        """Forget the estimate: the next measurement initialises it."""
        self._last: tuple[float, float, float, float, float, float] | None = None

    def start_at(self, x: float, y: float, theta: float) -> None:
        """Take a known start pose [m, m, rad] of the robot at rest as the estimate before the first measurement.

        The next measurement z(0) is then predicted from it (zero velocity before it) and corrected as any
        other, p(0) = s + L (z(0) - s) for a start s: its pose noise n(0) reaches the estimate as L n(0)
        (0.02 n(0) for tau = 0.5 s, Ts = 10 ms), as in the steady state, instead of n(0) when z(0)
        initialises it, which the MPCs' position gain turns into a start kick (volts for 1 mm at tick 0).
        For a start where robot and reference are known to coincide (the offline loop, tick 0 of a
        lockstep run); anywhere else the first measurement must initialise (`reset`).

        Raises
        ------
        EstimatorError
            If a value is not finite; the filter's state is then unchanged.
        """
        if not math.isfinite(x + y + theta):
            raise EstimatorError(f"start pose must be finite, got {(x, y, theta)}")
        self._last = (float(x), 0.0, float(y), 0.0, float(theta), 0.0)

    def shift(self, dx: float, dy: float, dtheta: float) -> None:
        """Move the estimate by (dx, dy, dtheta) [m, m, rad]: a caller's better prediction over the last interval.

        No-op before the first measurement.
        """
        if self._last is not None:
            px, vx, py, vy, pt, w = self._last
            self._last = (px + dx, vx, py + dy, vy, pt + dtheta, w)

    @property
    def initialized(self) -> bool:
        """True once a measurement has been taken since construction or `reset`."""
        return self._last is not None

    @property
    def estimate(self) -> tuple[float, float, float] | None:
        """The last estimate (x, y, theta), or None before the first measurement."""
        return None if self._last is None else self._last[0::2]

    def update(
        self, x: float, vx: float, y: float, vy: float, theta: float, w: float, dt_s: float | None = None
    ) -> tuple[float, float, float]:
        """Take one measurement and return the pose estimate.

        Parameters
        ----------
        x, vx, y, vy, theta, w
            The measured body state X = (x, x', y, y', theta, theta') of eq. (2)
            in the odom frame [m, m/s, rad, rad/s]; theta may be wrapped.
        dt_s
            Time since the previous measurement [s], > 0; None: one period.

        Returns
        -------
        tuple of float
            Estimated (x, y, theta); theta continuous from the first measurement.

        Raises
        ------
        EstimatorError
            If a value is not finite or dt_s is not > 0; the filter's state is then unchanged.

        Notes
        -----
        Runs on Python floats (the controller's per-tick path).
        """
        if not math.isfinite(x + vx + y + vy + theta + w):
            raise EstimatorError(f"measurement must be finite, got {(x, vx, y, vy, theta, w)}")
        if dt_s is None or dt_s == self.period_s:
            h, L = self._half_period, self.gain
        elif math.isfinite(dt_s) and dt_s > 0.0:
            h, L = 0.5 * dt_s, filter_gain(dt_s, self.time_constant_s)
        else:
            raise EstimatorError(f"dt_s must be finite and > 0, got {dt_s!r}")
        last = self._last
        if last is None:
            self._last = (x, vx, y, vy, theta, w)
            return x, y, theta
        px, vx0, py, vy0, pt, w0 = last
        if self._period_mean:
            dt = 2.0 * h
            a = w * dt
            if abs(a) < 1e-6:  # series of sin(a)/a and (1 - cos a)/a, error below 1e-19
                sdt, cdt = (1.0 - a * a / 6.0) * dt, 0.5 * a * dt
            else:
                sdt, cdt = math.sin(a) / w, (1.0 - math.cos(a)) / w
            px += sdt * vx + cdt * vy
            py += sdt * vy - cdt * vx
            pt += a
        else:
            px += h * (vx0 + vx)
            py += h * (vy0 + vy)
            pt += h * (w0 + w)
        px += L * (x - px)
        py += L * (y - py)
        pt += L * math.remainder(theta - pt, _TWO_PI)
        self._last = (px, vx, py, vy, pt, w)
        return px, py, pt


class OdometryFilterBatch:
    """The filters of B runs at once (`OdometryFilter` per run), each started at a known pose (`start_at`).

    Parameters
    ----------
    period_s, time_constant_s
        As for `OdometryFilter` (shared by the runs).
    twists
        Each run's twist model (`TWIST_MODELS`).
    start
        The start poses (x, y, theta), shape (B, 3).
    """

    def __init__(self, period_s: float, time_constant_s: float, twists: Sequence[str], start: np.ndarray) -> None:
        one = OdometryFilter(period_s, time_constant_s)  # checks the shared settings
        if any(twist not in TWIST_MODELS for twist in twists):
            raise EstimatorError(f"twists must be of {', '.join(TWIST_MODELS)}, got {sorted(set(twists))}")
        start = np.asarray(start, dtype=float)
        if start.shape != (len(twists), 3) or not np.all(np.isfinite(start)):
            raise EstimatorError(f"start must be {len(twists)} finite poses, got shape {start.shape}")
        self.period_s, self.time_constant_s, self.gain = one.period_s, one.time_constant_s, one.gain
        self._half_period = one._half_period
        self._period_mean = np.flatnonzero([twist == "period_mean" for twist in twists])  # the runs with that model
        self._last = np.zeros((6, len(twists)))  # one row per entry of the state
        self._last[0::2] = start.T

    def update(self, X: np.ndarray) -> np.ndarray:
        """`OdometryFilter.update` over one period of every run: measured states X (B, 6) in, estimates (B, 3) out.

        The same predictor per run (its twist model), correction and heading wrap as `update`, as arrays;
        the measurements are the caller's own (unchecked).
        """
        rows = np.ascontiguousarray(X.T)  # (6, B): one row per entry of the measured state
        last = self._last
        h, L = self._half_period, self.gain
        runs = self._period_mean
        predicted = last[0::2] + h * (last[1::2] + rows[1::2])  # the trapezoid's (x, y, theta)
        if len(runs):  # the period mean's: the SE(2) exponential of the twist, computed for those runs only
            vx, vy, w = rows[1::2, runs]
            dt = 2.0 * h
            a = w * dt
            small = np.abs(a) < 1e-6  # series of sin(a)/a and (1 - cos a)/a, error below 1e-19
            if small.any():
                with np.errstate(divide="ignore", invalid="ignore"):
                    sdt = np.where(small, (1.0 - a * a / 6.0) * dt, np.sin(a) / w)
                    cdt = np.where(small, 0.5 * a * dt, (1.0 - np.cos(a)) / w)
            else:
                sdt, cdt = np.sin(a) / w, (1.0 - np.cos(a)) / w
            x, y, theta = last[0::2, runs]
            predicted[:, runs] = (x + (sdt * vx + cdt * vy), y + (sdt * vy - cdt * vx), theta + a)
        new = np.empty_like(last)
        new[1::2] = rows[1::2]
        np.add(predicted[:2], L * (rows[0:4:2] - predicted[:2]), out=new[0:4:2])
        innovation = rows[4] - predicted[2]  # math.remainder's wrap:
        np.add(predicted[2], L * (innovation - _TWO_PI * np.round(innovation / _TWO_PI)), out=new[4])
        self._last = new
        return new[0::2].T
