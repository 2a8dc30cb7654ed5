"""B simulated Robotinos stepped together: the array form of `RobotinoPlant.step` with a batch axis.

Each run has its own state, wheel angles and held voltages, and its own
physical parameters; runs that share parameters share the step matrices of
`RobotinoPlant` (`_constant_matrices`: the heading rows and the substep maps'
polynomial in the heading change), so a step of the batch is, per parameter
group, one product for every heading quantity and two products per substep:

    v_(k+1) = M(eps_k) v_k,  M(eps) = sum_j b_j(eps) C_j   =>   v_(k+1) = sum_j b_j (C_j v_k),

the C_j v_k of all runs in one matrix product (B, 14) x (14, 8 x 14). A run
whose heading change leaves the polynomial's range (a turn rate beyond 20
rad/s), or a group with anisotropic friction, takes the exact expm maps of
`RobotinoPlant` for that run, as `RobotinoPlant.step` does. B = 1 is one run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from robotino_geom_mpc.model.plant import _BASIS, _CURRENTS, _N_LOOP, _ROWS, PlantError, \
    RobotinoPlant, _turn
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = ["PlantBatch"]


class PlantBatch:
    """B coupled Robotinos (body and drives) under held voltages, integrated as `RobotinoPlant` integrates one.

    Parameters
    ----------
    params
        The physical parameters of each run (B of them; equal ones share their matrices).
    substeps
        As for `RobotinoPlant`.

    Attributes
    ----------
    state : ndarray, shape (B, 12)
        Per run (x, x', y, y', theta, theta', i_1, i_2, i_3) and the wheel angles, from rest at the origin.
    time_s : float
        Simulated time since the start (the runs step together).
    """

    def __init__(self, params: Sequence[RobotinoParams], substeps: int | None = None) -> None:
        self.params = tuple(params)
        if not self.params:
            raise PlantError("a plant batch needs at least one run")
        groups: dict[RobotinoParams, list[int]] = {}
        for index, p in enumerate(self.params):
            groups.setdefault(p, []).append(index)
        self._groups = [(RobotinoPlant(p, substeps=substeps), np.array(rows)) for p, rows in groups.items()]
        self._loop_maps: dict[tuple[int, float], np.ndarray] = {}
        self.state = np.zeros((len(self.params), 12))
        self.time_s = 0.0

    @property
    def pose(self) -> np.ndarray:
        """(x, y, theta) per run, shape (B, 3)."""
        return self.state[:, 0:5:2]

    def odometry(self) -> tuple[np.ndarray, np.ndarray]:
        """The ideal measurement of every run, noise-free: poses (B, 3) and body-frame twists (v_x, v_y, theta')
        (B, 3), the array form of `RobotinoPlant.noisy_odometry_floats`.
        """
        x, vx, y, vy, theta, w = self.state[:, :6].T
        c, s = np.cos(theta), np.sin(theta)
        return self.state[:, 0:5:2].copy(), np.column_stack((c * vx + s * vy, -s * vx + c * vy, w))

    @property
    def wheel_angles(self) -> np.ndarray:
        """Integrated wheel angles (rim distance / r) per run [rad], shape (B, 3)."""
        return self.state[:, 9:12]

    def _stacked_maps(self, group: int, plant: RobotinoPlant, dt: float) -> np.ndarray:
        """(14, 8 x 11): column block j is the transpose of C_j's first 11 rows, so v @ it gives every C_j v.

        (The last 3 rows of every map pass the held voltages on.)
        """
        key = (group, dt)
        if key not in self._loop_maps:
            fitted = plant._matrices(dt).coefficients
            assert fitted is not None  # isotropic groups only (the fast path)
            coefficients = fitted.reshape(_BASIS, _N_LOOP, _N_LOOP)[:, : len(_ROWS)]
            self._loop_maps[key] = coefficients.transpose(2, 0, 1).reshape(_N_LOOP, _BASIS * len(_ROWS))
        return self._loop_maps[key]

    def step(self, voltages: np.ndarray, dt: float) -> np.ndarray:
        """Advance every run by dt [s] with its voltages (B, 3) [V] held; the peak currents of the step (B, 3).

        The peak of each drive is its largest |current| over the substep ends and the step's start, signed
        like the current at the step's end (the offline loop's record).

        Raises
        ------
        PlantError
            For voltages that are not (B, 3) finite numbers or a dt that is not a positive finite number.
        """
        U = np.asarray(voltages, dtype=float)
        if U.shape != (len(self.params), 3) or not np.all(np.isfinite(U)):
            raise PlantError(f"voltages must be finite with shape ({len(self.params)}, 3), got {U.shape}")
        if not (isinstance(dt, float) and math.isfinite(dt) and dt > 0.0):
            raise PlantError(f"dt must be a positive finite number of seconds, got {dt!r}")
        peaks = np.empty_like(U)
        for group, (plant, rows) in enumerate(self._groups):
            c = plant._matrices(dt)
            n = c.n
            w = np.concatenate((self.state[rows], U[rows]), axis=1)  # the augmented states (b, 15)
            heading = w @ c.heading_rows.T
            start, end, theta_end = heading[:, n * _BASIS : n * _BASIS + 3].T
            raw = heading[:, : n * _BASIS].reshape(len(rows), n, _BASIS)
            fast = np.abs(raw[:, :, 1]).max(axis=1) <= 1.0 if c.coefficients is not None else np.zeros(len(rows), bool)
            # Into each run's start frame: the loop vector (rotated planar pairs, then w[5:])
            x, vx, y, vy = w[:, :4].T
            cos, sin = np.cos(-start), np.sin(-start)
            v = np.column_stack((cos * x - sin * y, cos * vx - sin * vy, sin * x + cos * y, sin * vx + cos * vy,
                                 w[:, 5:]))
            trace = np.empty((n + 1, len(rows), len(_ROWS)))  # the loop vectors without the held voltages
            trace[0] = v[:, : len(_ROWS)]
            if fast.any():
                # the basis (1, e, .., e^6, beta) of each substep, e = eps / eps_max (`_EXPONENTS`)
                e = raw[:, :, 1]
                powers = [np.ones_like(e), e]
                for _ in range(_BASIS - 3):
                    powers.append(powers[-1] * e)
                basis = np.stack((*powers, raw[:, :, _BASIS - 1]), axis=2)[:, :, None, :]  # (b, n, 1, 8)
                stacked = self._stacked_maps(group, plant, dt)
                held = w[:, 12:] @ stacked[len(_ROWS) :]  # the voltages' share of every C_j v, the same each substep
                for k in range(n):
                    products = (trace[k] @ stacked[: len(_ROWS)] + held).reshape(-1, _BASIS, len(_ROWS))
                    trace[k + 1] = (basis[:, k] @ products)[:, 0]
            for b in np.flatnonzero(~fast):  # exact maps, as `RobotinoPlant.step` beyond the fit
                for k in range(n):
                    exact = _turn(raw[b, k, _BASIS - 1]) @ plant._substep_map(
                        raw[b, k, 1] * c.eps_max, heading[b, n * _BASIS + 3 + k], c.h)
                    trace[k + 1, b] = exact @ np.concatenate((trace[k, b], w[b, 12:]))
            x, vx, y, vy = trace[n, :, :4].T
            cos, sin = np.cos(end), np.sin(end)
            self.state[rows] = np.column_stack((cos * x - sin * y, cos * vx - sin * vy, sin * x + cos * y,
                                                sin * vx + cos * vy, theta_end, trace[n, :, 4:]))
            currents = trace[:, :, _CURRENTS]
            peaks[rows] = np.copysign(np.abs(currents).max(axis=0), currents[-1])
        self.time_s += dt
        return peaks
