"""C^3 time laws shared by the references of `reference.trajectories`, and their two evaluation backends.

Every formula here and in `reference.trajectories` is written once, with plain
arithmetic, and evaluated by one of two backends: `_Scalar` (Python floats and
`math`, the cheap path of a scalar `Reference.sample` and of `preview`, which
run at each control tick) and `_Vector` (numpy, for arrays of times).

* `septic`: the septic smoothstep, the rest-to-rest time law (C^3 joints, Remark 1);
* `_RampedPhase`: a phase whose rate ramps in and out with the septic (C^4 phase);
* `_compose`: derivatives of a curve evaluated at a time law (Faa di Bruno).
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["TrajectoryError", "septic"]

class TrajectoryError(RobotinoError, ValueError):
    """An unknown reference or an invalid reference option (message names the option)."""


class _Scalar:
    """Backend for one time: Python floats and `math`."""

    sin = staticmethod(math.sin)
    cos = staticmethod(math.cos)
    atan2 = staticmethod(math.atan2)

    @staticmethod
    def clip(x: float, lo: float, hi: float) -> float:
        return lo if x < lo else hi if x > hi else x

    @staticmethod
    def heading(psi: float) -> float:
        return psi - 2.0 * math.pi if psi > 0.5 * math.pi else psi

    @staticmethod
    def segment(t0: list[float], t: float) -> int:
        return min(max(bisect.bisect_right(t0, t) - 1, 0), len(t0) - 1)


class _Vector:
    """Backend for a 1-D array of times: numpy."""

    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    atan2 = staticmethod(np.arctan2)

    @staticmethod
    def clip(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
        return np.minimum(np.maximum(x, lo), hi)

    @staticmethod
    def heading(psi: np.ndarray | float) -> np.ndarray:
        return np.where(psi > 0.5 * math.pi, psi - 2.0 * math.pi, psi)

    @staticmethod
    def segment(t0: np.ndarray, t: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(t0) - 1)


_Backend = type[_Scalar] | type[_Vector]


def _septic(tau, xp: _Backend):  # noqa: ANN001, ANN202 - float or array
    tau = xp.clip(tau, 0.0, 1.0)
    q = tau * (1.0 - tau)
    s = tau**4 * (35.0 + tau * (-84.0 + tau * (70.0 - 20.0 * tau)))
    return s, 140.0 * q**3, 420.0 * q * q * (1.0 - 2.0 * tau), 840.0 * q * (1.0 - 5.0 * q)


def septic(tau: float | np.ndarray) -> tuple:
    """Septic smoothstep s(tau) = 35 tau^4 - 84 tau^5 + 70 tau^6 - 20 tau^7 and its derivatives.

    s(0) = 0, s(1) = 1 and s', s'', s''' vanish at both ends, so a rest-to-rest
    move p0 + (p1 - p0) s(t / T) is C^3 at its joints (Remark 1).
    s' = 140 q^3, s'' = 420 q^2 (1 - 2 tau), s''' = 840 q (1 - 5 q) with
    q = tau (1 - tau). `tau` is clipped to [0, 1] (hold before and after).

    Returns
    -------
    (s, ds/dtau, d2s/dtau2, d3s/dtau3), each shaped like `tau`.
    """
    return _septic(np.asarray(tau, dtype=float), _Vector)


def _ramp_deficit(tau, xp: _Backend):  # noqa: ANN001, ANN202
    """E(tau) = int_tau^1 (1 - s(u)) du: the phase lost to a ramp, E(0) = 1/2, E(1) = 0."""
    tau = xp.clip(tau, 0.0, 1.0)
    return tau**5 * (7.0 + tau * (-14.0 + tau * (10.0 - 2.5 * tau))) - tau + 0.5


def _compose(f: list, s: tuple) -> list:
    """Derivatives of the components of f(s(t)) up to the third (Faa di Bruno).

    `f` = [f, f_s, f_ss, f_sss], each a triple of components; `s` = (s, s', s'', s''').
    """
    _, s1, s2, s3 = s
    f0, f1, f2, f3 = f
    sq = s1 * s1
    cube, mixed = sq * s1, 3.0 * s1 * s2
    return [
        f0,
        [a * s1 for a in f1],
        [b * sq + a * s2 for a, b in zip(f1, f2)],
        [c * cube + b * mixed + a * s3 for a, b, c in zip(f1, f2, f3)],
    ]



class _RampedPhase:
    """Phase phi(t) advancing by `total` [rad] with a C^3 ramp-in and ramp-out of its rate.

    phi'(t) = rate h(t / T_r) h((D - t) / T_r) with h the septic smoothstep and
    T_r the ramp time: phi' rises from 0 to `rate`, stays there, and falls back
    to 0 at D = total / rate + T_r. Integrated in closed form,
    phi(t) = rate (t - T_r / 2 + T_r (E(t / T_r) - E((D - t) / T_r))) with E the
    ramp deficit. phi is C^4, so a smooth curve evaluated at phi(t) is C^3 at
    the start and end. t is clipped to [0, D] (rest outside).
    """

    def __init__(self, rate: float, ramp_s: float, total: float, name: str) -> None:
        if total / rate < ramp_s:
            raise TrajectoryError(
                f"{name}: ramp_s = {ramp_s:g} s is too long for the run (at most {total / rate:g} s)"
            )
        self.rate, self.ramp_s = rate, ramp_s
        self.duration_s = total / rate + ramp_s

    def evaluate(self, t, xp: _Backend, derivatives: bool):  # noqa: ANN001, ANN201
        """(phi,) or (phi, phi', phi'', phi''') at t."""
        t = xp.clip(t, 0.0, self.duration_s)
        tr, rate = self.ramp_s, self.rate
        tau_in, tau_out = t / tr, (self.duration_s - t) / tr
        phi = rate * (t - 0.5 * tr + tr * (_ramp_deficit(tau_in, xp) - _ramp_deficit(tau_out, xp)))
        if not derivatives:
            return (phi,)
        h_in, h_out = _septic(tau_in, xp), _septic(tau_out, xp)
        # The ramps never overlap: one factor is 1 wherever the other varies.
        return (
            phi,
            rate * h_in[0] * h_out[0],
            rate / tr * (h_in[1] * h_out[0] - h_in[0] * h_out[1]),
            rate / tr**2 * (h_in[2] * h_out[0] + h_in[0] * h_out[2]),
        )

