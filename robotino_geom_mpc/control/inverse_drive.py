"""Inverse DC drive: wheel voltages for commanded currents, U = R i + L di/dt + Km omega (eq. 10).

The controller holds each voltage over one control period Ts (zero-order
hold) while the armature current answers with tau = L / R (about 1.5 ms
against Ts = 10 ms), so the continuous formula needs a discrete reading.
The MPC model (eq. 49) holds the acceleration u, hence the wheel force and
the current, constant over the period: what moves the body is the current's
*average* over the period. This module chooses the voltage that makes that
average equal the commanded current.

Derivation (one drive, period [0, Ts], U held, back-EMF e(t) = Km (omega +
omega' t) with the motor speed omega measured at the tick and its rate
omega' from the commanded acceleration): L i' = U - R i - e(t) gives, with
alpha = exp(-Ts / tau) and phi = (tau / Ts)(1 - alpha),

    mean:  i_mean = phi i_0 + (1 - phi)(U - Km omega)/R - (Km omega'/R)(Ts/2 - tau (1 - phi))
    end:   i_end  = alpha i_0 + (1 - alpha)(U - Km omega)/R - (Km omega'/R)(Ts - tau (1 - alpha))

Solving i_mean = i* for U keeps the physical structure:

    U = R i* + L_d (i* - i_0)/Ts + Km (omega + t_e omega'),
    L_d = L (1 - alpha)/(1 - phi),   t_e = Ts / (2 (1 - phi)) - tau,

i.e. di/dt is the planned change of the current over the period (from its
value i_0 at the start towards the command i*), with an effective inductance
L_d (-> L when Ts >> tau, -> 2 L when Ts << tau, the linear-ramp limit) and
the back-EMF taken at the effective time t_e inside the period. i_0 is not
measured: the drive predicts it with the `end` formula from the voltage it
actually applied (after saturation), so there is no difference of noisy
measurements; its error decays by alpha (~1e-3) per period.

For the Robotino 3 preset at Ts = 10 ms: tau = 1.50 ms, L_d = 10.45 mH
(1.17 L), t_e = 4.38 ms. On the coupled plant a current ramp of 20 mA per
period is tracked to 0.06 mA, where the textbook reading
L (i*_k - i*_{k-1})/Ts with the back-EMF at the tick lags by 9.5 mA
(test/test_drive.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.arrays import checked_array, largest_abs
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = ["DriveError", "ZOHDrive", "InverseDrive", "InverseDriveBatch"]

_SATURATION_PASSES = 4  # fixed-point passes for the mean current under clipped voltages


class DriveError(RobotinoError, ValueError):
    """A drive input with the wrong shape or a non-finite value."""


def _mean_current(d: ZOHDrive | _ZOHBatch, i_start, U, omega, omega_rate):
    """The period average of the current for a held voltage U (module notes), on `d`'s coefficients."""
    return d.phi * i_start + d._m_volt * (U - d.torque_constant * omega) - d._m_rate * omega_rate


class ZOHDrive:
    """Exact zero-order-hold relations of one armature circuit over a period (see the module notes).

    All methods are linear in their array arguments and accept any common
    shape, so the constrained mode applies them to affine coefficient arrays.

    Parameters
    ----------
    resistance_ohm, inductance_h, torque_constant
        R, L and Km of eq. (10).
    period_s
        Ts, the period over which the voltage is held.

    Attributes
    ----------
    tau_s
        L / R.
    alpha
        exp(-Ts / tau): the share of the start current left at the end of the period.
    phi
        (tau / Ts)(1 - alpha): the start current's weight in the period average.
    effective_inductance_h
        L_d = L (1 - alpha)/(1 - phi).
    emf_time_s
        t_e = Ts / (2 (1 - phi)) - tau: when in the period the back-EMF is taken.
    """

    def __init__(self, resistance_ohm: float, inductance_h: float, torque_constant: float, period_s: float) -> None:
        for name, value in (
            ("resistance_ohm", resistance_ohm),
            ("inductance_h", inductance_h),
            ("torque_constant", torque_constant),
            ("period_s", period_s),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise DriveError(f"{name} must be finite and > 0, got {value!r}")
        self.resistance_ohm = float(resistance_ohm)
        self.inductance_h = float(inductance_h)
        self.torque_constant = float(torque_constant)
        self.period_s = float(period_s)
        self.tau_s = self.inductance_h / self.resistance_ohm
        ratio = self.period_s / self.tau_s
        self.alpha = math.exp(-ratio)
        self.phi = -math.expm1(-ratio) / ratio
        self.effective_inductance_h = self.inductance_h * (1.0 - self.alpha) / (1.0 - self.phi)
        self.emf_time_s = self.period_s / (2.0 * (1.0 - self.phi)) - self.tau_s
        # coefficients of the three relations
        R, Km, tau = self.resistance_ohm, self.torque_constant, self.tau_s
        self._v_step = self.effective_inductance_h / self.period_s
        self._v_cmd = R + self._v_step
        self._v_rate = Km * self.emf_time_s
        self._m_volt = (1.0 - self.phi) / R
        self._m_rate = Km / R * (0.5 * self.period_s - tau * (1.0 - self.phi))
        self._e_volt = (1.0 - self.alpha) / R
        self._e_rate = Km / R * (self.period_s - tau * (1.0 - self.alpha))

    def voltage(self, i_cmd, i_start, omega, omega_rate):
        """U = R i* + L_d (i* - i_0)/Ts + Km (omega + t_e omega'): the period average of i equals i*."""
        return self._v_cmd * i_cmd - self._v_step * i_start + self.torque_constant * omega + self._v_rate * omega_rate

    def mean_current(self, i_start, U, omega, omega_rate):
        """Average of the current over the period for a held voltage U."""
        return _mean_current(self, i_start, U, omega, omega_rate)

    def end_current(self, i_start, U, omega, omega_rate, elapsed_s: float | None = None):
        """Current at the end of the period, or after `elapsed_s` [s] > 0, for a held voltage U."""
        alpha, e_volt, e_rate = (
            (self.alpha, self._e_volt, self._e_rate) if elapsed_s is None else self.end_coefficients(elapsed_s)
        )
        return alpha * i_start + e_volt * (U - self.torque_constant * omega) - e_rate * omega_rate

    def end_coefficients(self, elapsed_s: float) -> tuple[float, float, float]:
        """(alpha, (1 - alpha)/R, Km/R (t - tau (1 - alpha))) of the `end` relation over t = `elapsed_s` [s] > 0.

        Raises
        ------
        DriveError
            For a non-finite or non-positive `elapsed_s`.
        """
        if not (math.isfinite(elapsed_s) and elapsed_s > 0.0):
            raise DriveError(f"elapsed_s must be finite and > 0, got {elapsed_s!r}")
        R, Km, tau = self.resistance_ohm, self.torque_constant, self.tau_s
        decay = -math.expm1(-elapsed_s / tau)  # 1 - alpha, exact for small t
        return 1.0 - decay, decay / R, Km / R * (elapsed_s - tau * decay)


class InverseDrive:
    """The three inverse drives with their current predictor and the supply limit.

    Parameters
    ----------
    p
        Motor parameters R, L, Km and the supply voltage.
    period_s
        Control period Ts over which each voltage is held.
    """

    def __init__(self, p: RobotinoParams, period_s: float) -> None:
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise DriveError(f"period_s must be finite and > 0, got {period_s!r}")
        self.zoh = ZOHDrive(p.resistance_ohm, p.inductance_h, p.torque_constant_n_m_per_a, float(period_s))
        self.period_s = self.zoh.period_s
        self.supply_voltage_v = p.supply_voltage_v
        self.current_per_force = p.r / (p.gear_ratio * p.torque_constant_n_m_per_a)  # i = F r / (gear Km) [A/N]
        # The relations are linear: their coefficients over (i*, i_0, omega, omega'), read off the
        # basis, give an unclipped period in a few scalar products per wheel.
        basis = np.eye(4)
        voltage_row = self.zoh.voltage(*basis)
        self._voltage_row = tuple(voltage_row.tolist())
        self._end_row = tuple(self.zoh.end_current(basis[1], voltage_row, basis[2], basis[3]).tolist())
        self.reset()

    @property
    def current_estimate(self) -> list[float]:
        """Predicted currents at the start of the next period [A] (one period after the last, or as `advance` set),
        three Python floats (a copy).
        """
        return list(self._i0)

    def reset(self, currents: np.ndarray | None = None) -> None:
        """Start again from known currents (default zero: a robot at rest, drives off)."""
        self._i0 = [0.0, 0.0, 0.0] if currents is None else self._vec(currents, "currents").tolist()
        self._last: tuple[Sequence[float], ...] | None = None  # (i_0, U, omega, omega') of the last period
        self._one_period = self._i0  # the step's own prediction, one period on

    def currents(self, forces: Sequence[float]) -> list[float]:
        """Wheel currents i = F r / (gear Km) [A] for wheel forces F [N] (erratum 4), on Python floats."""
        k = self.current_per_force
        return [k * forces[0], k * forces[1], k * forces[2]]

    def advance(self, elapsed_s: float) -> None:
        """Re-predict the start currents for a next tick `elapsed_s` [s] after the last one instead of one period.

        The last voltages were held until the next command, so the start
        current is the `end` relation over the time that really elapsed
        (e.g. 2 Ts after a lost tick, ~0 after a duplicated one), with the
        back-EMF ramp of that period continued. A no-op before the first
        period; exactly one period restores the step's own prediction.

        Raises
        ------
        DriveError
            For a non-finite or non-positive `elapsed_s`.
        """
        if elapsed_s == self.period_s:
            self._i0 = self._one_period
            return
        alpha, e_volt, e_rate = self.zoh.end_coefficients(elapsed_s)
        if self._last is None:
            return
        Km = self.zoh.torque_constant
        self._i0 = [
            alpha * i + e_volt * (U - Km * w) - e_rate * r for i, U, w, r in zip(*self._last)
        ]

    def limited_step(
        self,
        i_cmd: Sequence[float],
        omega: Sequence[float],
        omega_rate: Sequence[float],
        rate_at_rest: Callable[[], Sequence[float]],
        current_limit: float,
        rate_of_current: Callable[[np.ndarray], Sequence[float] | np.ndarray] | None = None,
    ) -> tuple[Sequence[float], bool, Sequence[float], float]:
        """`step` with the commanded currents scaled by one factor s in (0, 1] to keep the limits.

        Parameters
        ----------
        i_cmd, omega, omega_rate, rate_of_current
            As for `step`; `omega_rate` is the motor-speed rate under the full command.
        rate_at_rest
            The motor-speed rate under a zero command (friction and the turning frame only).
            Called only when a limit binds: the rate is affine in s between the two.
        current_limit
            I_max [A] > 0 on the period-average and the end-of-period current of every wheel.

        Returns
        -------
        voltages, saturated, mean_current
            As for `step`, for the scaled command.
        scale : float
            s: 1 when the command keeps |i*| <= I_max, |i_end| <= I_max and |U| <= supply;
            otherwise the largest s for which all hold, so the largest wheel sits at its limit.

        Notes
        -----
        The period average i* is the command itself; the current relaxes from
        i_0 towards the end value (`ZOHDrive.end_current`), so with |i_0| and
        |i_end| at most I_max the current stays within I_max over the period
        up to the small hump where the back-EMF rises inside it. Every bounded
        quantity is affine in s, a + s b: the binding s is (+-I_max - a) / b.
        A row already beyond its limit at s = 0 (e.g. a back-EMF above the
        supply) cannot be helped by scaling and is left to the supply clip of `step`.
        """
        i0, last, one_period = self._i0, self._last, self._one_period
        voltages, saturated, mean = self.step(i_cmd, omega, omega_rate, rate_of_current)
        end = self._i0
        if not saturated and max(abs(i_cmd[0]), abs(i_cmd[1]), abs(i_cmd[2]),
                                 abs(end[0]), abs(end[1]), abs(end[2])) <= current_limit:
            return voltages, saturated, mean, 1.0
        self._i0, self._last, self._one_period = i0, last, one_period
        rest = rate_at_rest()
        ec, es, ew, er = self._end_row
        vc, vs, vw, vr = self._voltage_row
        supply, scale = self.supply_voltage_v, 1.0
        for c, s0, w, r0, r1 in zip(i_cmd, i0, omega, rest, omega_rate):
            dr = r1 - r0
            for a, b, bound in (
                (0.0, c, current_limit),
                (es * s0 + ew * w + er * r0, ec * c + er * dr, current_limit),
                (vs * s0 + vw * w + vr * r0, vc * c + vr * dr, supply),
            ):
                full = a + b
                if abs(full) > bound and abs(a) < bound:
                    scale = min(scale, (math.copysign(bound, full) - a) / b)
        scaled_rate = [r0 + scale * (r1 - r0) for r0, r1 in zip(rest, omega_rate)]
        voltages, saturated, mean = self.step([scale * c for c in i_cmd], omega, scaled_rate, rate_of_current)
        return voltages, saturated, mean, scale

    @staticmethod
    def _vec(value: object, name: str) -> np.ndarray:
        return checked_array(value, (3,), name, DriveError)

    def step(
        self,
        i_cmd: Sequence[float],
        omega: Sequence[float],
        omega_rate: Sequence[float],
        rate_of_current: Callable[[np.ndarray], Sequence[float] | np.ndarray] | None = None,
    ) -> tuple[Sequence[float], bool, Sequence[float]]:
        """Voltages for one period and the current they give.

        Parameters
        ----------
        i_cmd
            Commanded (period-average) currents i* [A], i = F r / (gear Km).
        omega
            Motor speeds at the tick [rad/s] (model.motor_speeds of the measured velocity).
        omega_rate
            Their rate over the period [rad/s^2] under the commanded acceleration.
        rate_of_current
            Optional: the motor-speed rate a given mean current causes. Used
            only when a voltage is clipped, since the body then accelerates
            less than commanded, which changes the back-EMF and thus the
            current; the mean current is found by fixed-point iteration (the
            map contracts by about Km^2 gear^2 Ts / (2 R r^2 M) ~ 0.02 per pass).

        Returns
        -------
        voltages : sequence of 3 floats
            Clipped to +-supply.
        saturated : bool
            True when any voltage was clipped.
        mean_current : sequence of 3 floats
            The period-average current the clipped voltages give (i_cmd itself unless saturated).
        """
        vc, vs, vw, vr = self._voltage_row
        (c0, c1, c2), (s0, s1, s2), (w0, w1, w2), (r0, r1, r2) = i_cmd, self._i0, omega, omega_rate
        U = [vc * c0 + vs * s0 + vw * w0 + vr * r0, vc * c1 + vs * s1 + vw * w1 + vr * r1,
             vc * c2 + vs * s2 + vw * w2 + vr * r2]
        limit = self.supply_voltage_v
        if max(abs(U[0]), abs(U[1]), abs(U[2])) <= limit:
            self._last = (self._i0, U, omega, omega_rate)
            ec, es, ew, er = self._end_row
            self._i0 = [
                ec * c0 + es * s0 + ew * w0 + er * r0,
                ec * c1 + es * s1 + ew * w1 + er * r1,
                ec * c2 + es * s2 + ew * w2 + er * r2,
            ]
            self._one_period = self._i0
            return U, False, i_cmd
        i0 = self._i0
        zoh, i0_arr = self.zoh, np.array(i0)
        speed, rate = np.asarray(omega, dtype=float), np.asarray(omega_rate, dtype=float)
        clipped = np.clip(U, -limit, limit)
        mean = zoh.mean_current(i0_arr, clipped, speed, rate)
        if rate_of_current is not None:
            for _ in range(_SATURATION_PASSES):
                rate = np.asarray(rate_of_current(mean), dtype=float)
                mean = zoh.mean_current(i0_arr, clipped, speed, rate)
        self._i0 = zoh.end_current(i0_arr, clipped, speed, rate).tolist()
        self._last = (i0, clipped.tolist(), speed.tolist(), rate.tolist())
        self._one_period = self._i0
        return clipped.tolist(), True, mean.tolist()


class _ZOHBatch:
    """`ZOHDrive`'s coefficients of B runs' drives, each a (B, 3) array (a run's value on its three wheels)."""

    def __init__(self, drives: Sequence[ZOHDrive]) -> None:
        column = lambda name: _column([getattr(d, name) for d in drives])  # noqa: E731
        self.phi, self.alpha, self.torque_constant = column("phi"), column("alpha"), column("torque_constant")
        self._m_volt, self._m_rate = column("_m_volt"), column("_m_rate")
        self._e_volt, self._e_rate = column("_e_volt"), column("_e_rate")

    def mean_current(self, i_start: np.ndarray, U: np.ndarray, omega: np.ndarray,
                     omega_rate: np.ndarray) -> np.ndarray:
        """`ZOHDrive.mean_current` of each run's drives."""
        return _mean_current(self, i_start, U, omega, omega_rate)

    def end_current(self, i_start: np.ndarray, U: np.ndarray, omega: np.ndarray,
                    omega_rate: np.ndarray) -> np.ndarray:
        """`ZOHDrive.end_current` over one period of each run's drives."""
        return self.alpha * i_start + self._e_volt * (U - self.torque_constant * omega) - self._e_rate * omega_rate


def _column(values: Sequence[object]) -> np.ndarray:
    """Per-run values (B, ...) repeated over the three wheels: (B, ..., 3) (a (B, 1) column broadcast over rows of
    three costs numpy four times as much).
    """
    return np.repeat(np.array(values, dtype=float)[..., None], 3, axis=-1)


class InverseDriveBatch:
    """The inverse drives of B robots at once (`InverseDrive` per run): every coefficient and the current estimate
    of shape (B, 3), a run's value on its three wheels.

    Parameters
    ----------
    robots
        Each run's motor parameters and supply voltage (B >= 1).
    period_s
        Control period Ts, shared by the runs.
    """

    def __init__(self, robots: Sequence[RobotinoParams], period_s: float) -> None:
        made: dict[tuple[float, ...], InverseDrive] = {}  # runs with the same drive share its coefficients
        keys = [(p.resistance_ohm, p.inductance_h, p.torque_constant_n_m_per_a, p.supply_voltage_v, p.r, p.gear_ratio)
                for p in robots]
        runs = [made[key] if key in made else made.setdefault(key, InverseDrive(p, period_s))
                for key, p in zip(keys, robots)]
        self.zoh = _ZOHBatch([run.zoh for run in runs])
        self.period_s = runs[0].period_s
        self.supply_voltage_v = _column([run.supply_voltage_v for run in runs])
        self.current_per_force = _column([run.current_per_force for run in runs])
        self._voltage_row = _column([run._voltage_row for run in runs]).transpose(1, 0, 2).copy()  # (4, B, 3)
        self._end_row = _column([run._end_row for run in runs]).transpose(1, 0, 2).copy()
        self.reset()

    @property
    def current_estimate(self) -> np.ndarray:
        """Predicted currents at the start of the next period [A], (B, 3)."""
        return self._i0.copy()

    def reset(self) -> None:
        """Start again from zero currents (robots at rest, drives off)."""
        self._i0 = np.zeros(self.supply_voltage_v.shape)

    def step(
        self, i_cmd: np.ndarray, omega: np.ndarray, omega_rate: np.ndarray,
        rate_of_current: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`InverseDrive.step` of each run: arrays (B, 3) in; voltages (B, 3), saturated (B,), mean currents (B, 3).

        The same relations in the same order as `InverseDrive.step`, run by run: an unclipped run takes the voltage
        and end-current rows, a clipped one the ZOH relations with the mean current found by the fixed point
        (`rate_of_current` maps (B, 3) mean currents to (B, 3) motor-speed rates).
        """
        vc, vs, vw, vr = self._voltage_row
        i0, supply = self._i0, self.supply_voltage_v
        U = vc * i_cmd + vs * i0 + vw * omega + vr * omega_rate
        saturated = largest_abs(U) > supply[:, 0]
        ec, es, ew, er = self._end_row
        end = ec * i_cmd + es * i0 + ew * omega + er * omega_rate
        mean = i_cmd
        if np.count_nonzero(saturated):  # (a quarter of `any`'s cost on a batch)
            clipped = np.clip(U, -supply, supply)
            rate = omega_rate
            clipped_mean = self.zoh.mean_current(i0, clipped, omega, rate)
            if rate_of_current is not None:
                for _ in range(_SATURATION_PASSES):
                    rate = rate_of_current(clipped_mean)
                    clipped_mean = self.zoh.mean_current(i0, clipped, omega, rate)
            rows = saturated[:, None]
            U = np.where(rows, clipped, U)
            mean = np.where(rows, clipped_mean, i_cmd)
            end = np.where(rows, self.zoh.end_current(i0, clipped, omega, rate), end)
        self._i0 = end
        return U, saturated, mean

    def limited_step(
        self, i_cmd: np.ndarray, omega: np.ndarray, omega_rate: np.ndarray, rate_at_rest: Callable[[], np.ndarray],
        current_limit: float, rate_of_current: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`InverseDrive.limited_step` of each run: as `step`, plus the scale s (B,) of each run's command.

        A run whose full command keeps its limits keeps it (s = 1); every other one is stepped again from the
        same start currents with its command scaled by the largest s whose affine bounds a + s b all hold
        (the candidates of `InverseDrive.limited_step`).
        """
        i0 = self._i0
        U, saturated, mean = self.step(i_cmd, omega, omega_rate, rate_of_current)
        end = self._i0
        if not np.count_nonzero(saturated) and np.abs(i_cmd).max() <= current_limit \
                and np.abs(end).max() <= current_limit:  # every run keeps its command (the common case, at once)
            return U, saturated, mean, np.ones(len(U))
        keep = ~saturated & (np.maximum(largest_abs(i_cmd), largest_abs(end)) <= current_limit)
        scale = np.ones(len(keep))
        rest = rate_at_rest()
        ec, es, ew, er = self._end_row
        vc, vs, vw, vr = self._voltage_row
        dr = omega_rate - rest
        bounds: tuple[tuple[np.ndarray, np.ndarray, float | np.ndarray], ...] = (
            (np.zeros_like(i_cmd), i_cmd, current_limit),
            (es * i0 + ew * omega + er * rest, ec * i_cmd + er * dr, current_limit),
            (vs * i0 + vw * omega + vr * rest, vc * i_cmd + vr * dr, self.supply_voltage_v),
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            for a, b, bound in bounds:
                full = a + b
                binds = (np.abs(full) > bound) & (np.abs(a) < bound)
                candidate = np.where(binds, (np.copysign(bound, full) - a) / b, np.inf)
                scale = np.minimum(scale, candidate.min(axis=-1))
        scale = np.where(keep, 1.0, scale)
        self._i0 = i0
        scaled = scale[:, None]
        U2, saturated2, mean2 = self.step(scaled * i_cmd, omega, rest + scaled * dr, rate_of_current)
        rows = keep[:, None]
        self._i0 = np.where(rows, end, self._i0)
        return (np.where(rows, U, U2), np.where(keep, saturated, saturated2), np.where(rows, mean, mean2), scale)
