"""B simulated Robotinos stepped together: the array form of `RobotinoPlant.step` with a batch axis.

Each run has its own state, wheel angles and held voltages, and its own
physical parameters; runs that share parameters share the step matrices of
`RobotinoPlant` (`_constant_matrices`: the heading rows and the substep maps'
polynomial in the heading change), so a step of the batch is, per parameter
group, one product for every heading quantity and two products per substep:

    v_(k+1) = M(eps_k) v_k,  M(eps) = sum_j b_j(eps) C_j   =>   v_(k+1) = sum_j b_j (C_j v_k),

the C_j v_k of all runs in one matrix product (B, 8) x (8, 8 x 11) (the held voltages' share once a step;
the wheel angles only pass through C_0, as the identity, so they are added, not multiplied). A run
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

_WHEELS = slice(8, 11)  # the wheel angles of the loop vector: C_0 passes them on (identity), no other C_j sees them
_DROPPED = 2.0**-56  # the terms of the substep maps' polynomial a step may leave out, relative (`PlantBatch._degree`)


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
        self._whole = len(self._groups) == 1  # one group: its rows are all runs, in order (no gather, no scatter)
        self._loop_maps: dict[tuple[int, float], list[tuple[np.ndarray, np.ndarray]]] = {}
        self._term_sizes: dict[tuple[int, float], np.ndarray] = {}
        self._columns = np.zeros((12, len(self.params)))  # the state, run by column (contiguous rows per quantity)
        self.time_s = 0.0

    @property
    def state(self) -> np.ndarray:
        """The state per run, shape (B, 12) (a view)."""
        return self._columns.T

    @property
    def pose(self) -> np.ndarray:
        """(x, y, theta) per run, shape (B, 3)."""
        return self.state[:, 0:5:2]

    def odometry(self) -> tuple[np.ndarray, np.ndarray]:
        """The ideal measurement of every run, noise-free: poses (B, 3) and body-frame twists (v_x, v_y, theta')
        (B, 3), the array form of `RobotinoPlant.noisy_odometry_floats`.
        """
        x, vx, y, vy, theta, w = self._columns[:6]
        c, s = np.cos(theta), np.sin(theta)
        return self.state[:, 0:5:2].copy(), np.column_stack((c * vx + s * vy, -s * vx + c * vy, w))

    @property
    def wheel_angles(self) -> np.ndarray:
        """Integrated wheel angles (rim distance / r) per run [rad], shape (B, 3)."""
        return self.state[:, 9:12]

    def _stacked_maps(self, group: int, plant: RobotinoPlant, dt: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per degree J = 0 .. 6: the substep maps' coefficients C_0 .. C_J and C_beta (the hand-over term)
        on the loop vector's first 8 entries and on the held voltages, ((J + 2) x 11, 8) and ((J + 2) x 11, 3).

        Row block j is C_j's first 11 rows, so C @ v gives every C_j v. Rows 8-10 of the loop vector, the
        wheel angles, are left out: C_0 passes them on (identity) and no other C_j sees them (checked here),
        so `step` adds them instead of multiplying.
        """
        key = (group, dt)
        if key not in self._loop_maps:
            fitted = plant._matrices(dt).coefficients
            assert fitted is not None  # isotropic groups only (the fast path)
            coefficients = fitted.reshape(_BASIS, _N_LOOP, _N_LOOP)[:, : len(_ROWS)]
            passes = np.zeros((_BASIS, len(_ROWS), 3))
            passes[0, _WHEELS] = np.eye(3)
            if not np.array_equal(coefficients[:, :, _WHEELS], passes):
                raise PlantError("the substep maps must pass the wheel angles on unchanged")
            maps = []
            for degree in range(_BASIS - 1):
                kept = coefficients[[*range(degree + 1), _BASIS - 1]].reshape(-1, _N_LOOP)
                maps.append((np.ascontiguousarray(kept[:, : _WHEELS.start]),
                             np.ascontiguousarray(kept[:, len(_ROWS) :])))
            self._loop_maps[key] = maps
            # the row sums of |C_j| beyond the wheel angles: the largest change a term e^j C_j can make
            size = np.abs(np.delete(coefficients, _WHEELS, axis=2)).sum(axis=2).max(axis=1)
            self._term_sizes[key] = size[: _BASIS - 1]
        return self._loop_maps[key]

    def _degree(self, key: tuple[int, float], e: float) -> int:
        """The lowest degree J whose dropped terms, sum over j > J of e^j |C_j|, stay below `_DROPPED`.

        `e` is the largest |eps / eps_max| of the step (eps / eps_max = turn rate / 20 rad/s). The terms fall
        off fast (|C_j| about 4.5, 0.12, 2.3e-3, 3.0e-5, 3.2e-7, 2.7e-9, 2.2e-11 for the Robotino 3 at 2.5 ms
        substeps), so a batch turning at most at 0.01 rad/s (|e| 5e-4) needs the terms up to e^3, one at
        0.1 rad/s those up to e^4: what is dropped changes no entry by more than `_DROPPED` times the largest
        |entry| of the loop vector and the held voltages, a sixteenth of its rounding unit.
        """
        size = self._term_sizes[key]
        dropped = 0.0
        for degree in range(len(size) - 1, 0, -1):
            dropped += e ** degree * size[degree]
            if dropped > _DROPPED:
                return degree
        return 0

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
        peaks = np.empty((3, len(self.params)))
        for group, (plant, rows) in enumerate(self._groups):
            c = plant._matrices(dt)
            n = c.n
            # the augmented states (15, b), one run per column
            w = np.concatenate((self._columns, U.T)) if self._whole else \
                np.concatenate((self._columns[:, rows], U[rows].T))
            b = w.shape[1]
            heading = c.heading_rows @ w
            start, end, theta_end = heading[n * _BASIS : n * _BASIS + 3]
            raw = heading[: n * _BASIS].reshape(n, _BASIS, b)
            turn = np.abs(raw[:, 1]).max(axis=0)  # each run's largest |eps / eps_max| of the step
            fast = turn <= 1.0 if c.coefficients is not None else np.zeros(b, bool)
            # Into each run's start frame: the loop vector (rotated planar pairs, then w[5:])
            x, vx, y, vy = w[:4]
            cos, sin = np.cos(start), np.sin(start)  # cos(-start) = cos, sin(-start) = -sin
            trace = np.empty((n + 1, len(_ROWS), b))  # the loop vectors without the held voltages
            trace[0, 0], trace[0, 1] = cos * x + sin * y, cos * vx + sin * vy
            trace[0, 2], trace[0, 3] = cos * y - sin * x, cos * vy - sin * vx
            trace[0, 4:] = w[5:12]
            if fast.any():
                # the basis (1, e, .., e^J, beta) of each substep, e = eps / eps_max (`_EXPONENTS`): (n, J + 2, b)
                maps = self._stacked_maps(group, plant, dt)
                degree = self._degree((group, dt), float(turn.max() if fast.all() else turn[fast].max()))
                moving, driving = maps[degree]
                basis = np.empty((n, degree + 2, b))
                basis[:, 0] = 1.0
                basis[:, degree + 1] = raw[:, _BASIS - 1]
                for j in range(1, degree + 1):
                    np.multiply(basis[:, j - 1], raw[:, 1], out=basis[:, j])
                held = driving @ w[12:]  # the voltages' share of every C_j v, the same each substep
                for k in range(n):
                    products = (moving @ trace[k, : _WHEELS.start] + held).reshape(degree + 2, len(_ROWS), b)
                    np.einsum("jib,jb->ib", products, basis[k], out=trace[k + 1])
                    trace[k + 1, _WHEELS] += trace[k, _WHEELS]  # C_0's identity on them
            for r in np.flatnonzero(~fast):  # exact maps, as `RobotinoPlant.step` beyond the fit
                for k in range(n):
                    exact = _turn(raw[k, _BASIS - 1, r]) @ plant._substep_map(
                        raw[k, 1, r] * c.eps_max, heading[n * _BASIS + 3 + k, r], c.h)
                    trace[k + 1, :, r] = exact @ np.concatenate((trace[k, :, r], w[12:, r]))
            x, vx, y, vy = trace[n, :4]
            cos, sin = np.cos(end), np.sin(end)
            out = self._columns if self._whole else np.empty((12, b))
            out[0], out[1], out[2], out[3] = cos * x - sin * y, cos * vx - sin * vy, sin * x + cos * y, \
                sin * vx + cos * vy
            out[4], out[5:] = theta_end, trace[n, 4:]
            currents = trace[:, _CURRENTS]
            largest = np.abs(currents).max(axis=0)
            if self._whole:
                np.copysign(largest, currents[-1], out=peaks)
            else:
                self._columns[:, rows] = out
                peaks[:, rows] = np.copysign(largest, currents[-1])
        self.time_s += dt
        return peaks.T
