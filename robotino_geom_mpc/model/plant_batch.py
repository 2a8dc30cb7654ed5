"""B simulated Robotinos stepped together: the array form of `RobotinoPlant.step` with a batch axis.

Each run has its own state, wheel angles and held voltages, and its own
physical parameters; runs that share parameters share the step matrices of
`RobotinoPlant` (`_constant_matrices`: the heading rows and the substep maps'
polynomial in the heading change), so a step of the batch is, per parameter
group, one product for every heading quantity and two products per substep:

    v_(k+1) = M(eps_k) v_k,  M(eps) = sum_j b_j(eps) C_j   =>   v_(k+1) = sum_j b_j (C_j v_k),

the C_j v_k of all runs in one matrix product ((J + 2) x 11, 11) x (11, B) on the held voltages and the
loop vector's first 8 entries (the wheel angles only pass through C_0, as the identity, so they are
added, not multiplied), combined with one einsum. A run whose heading change leaves the polynomial's
range (a turn rate beyond 20 rad/s), or a group with anisotropic friction, takes the exact expm maps of
`RobotinoPlant` for that run, as `RobotinoPlant.step` does. B = 1 is one run. The work arrays are kept
from step to step (`_Work`): arrays of this size, allocated afresh, cost more than the products.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from robotino_geom_mpc.model.plant import _BASIS, _N_LOOP, _ROWS, PlantError, RobotinoPlant, _StepCache, _turn
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = ["PlantBatch"]

# The rows of `_Work.trace`: the held voltages, then `RobotinoPlant`'s loop vector's first 11 entries (x, x', y,
# y' in the frame, theta', the currents, the wheel angles): one product takes rows 0-10 to rows 3-13.
_HELD, _MOVED, _LOOP, _PLANAR = slice(0, 3), slice(0, 11), slice(3, 14), slice(3, 7)
_THETA_RATE, _CURRENT_ROWS, _WHEEL_ROWS = 7, slice(8, 11), slice(11, 14)
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
        self._loop_maps: dict[tuple[int, float], list[np.ndarray]] = {}
        self._term_sizes: dict[tuple[int, float], np.ndarray] = {}
        self._work: dict[tuple[int, float], _Work] = {}
        # the augmented states w (15, B), one run per column: the state (each quantity a contiguous row), then
        # the held voltages
        self._augmented = np.zeros((15, len(self.params)))
        self._columns = self._augmented[:12]
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
        (B, 3), the array form of `RobotinoPlant.noisy_odometry`.
        """
        x, vx, y, vy, theta, w = self._columns[:6]
        c, s = np.cos(theta), np.sin(theta)
        twist = np.empty((len(theta), 3))
        np.add(c * vx, s * vy, out=twist[:, 0])
        np.add(-s * vx, c * vy, out=twist[:, 1])
        twist[:, 2] = w
        return self.state[:, 0:5:2].copy(), twist

    @property
    def wheel_angles(self) -> np.ndarray:
        """Integrated wheel angles (rim distance / r) per run [rad], shape (B, 3)."""
        return self.state[:, 9:12]

    def _stacked_maps(self, group: int, plant: RobotinoPlant, dt: float) -> list[np.ndarray]:
        """Per degree J = 0 .. 6: the substep maps' coefficients C_0 .. C_J and C_beta (the hand-over term)
        on the held voltages and the loop vector's first 8 entries (`_Work.trace`'s rows 0-10), ((J + 2) x 11, 11).

        Row block j is C_j's first 11 rows, so C @ v gives every C_j v. The wheel angles are left out: C_0
        passes them on (identity) and no other C_j sees them (checked here), so `step` adds them instead of
        multiplying.
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
                maps.append(np.hstack((kept[:, len(_ROWS) :], kept[:, : _WHEELS.start])))
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
        return self.advance(U, dt, np.empty((len(self.params), 3)))

    def advance(self, voltages: np.ndarray, dt: float, out: np.ndarray) -> np.ndarray:
        """`step` without its checks, the peak currents into `out` (B, 3) (returned): for a loop that passes
        float arrays (B, 3) and a valid dt of its own.

        Non-finite voltages are not refused here: they make the states non-finite (which the offline loop's
        metrics refuse).
        """
        for group, (plant, rows) in enumerate(self._groups):
            self._advance_group(group, plant, rows, voltages, dt, out.T)
        self.time_s += dt
        return out

    def _work_of(self, group: int, plant: RobotinoPlant, dt: float, b: int) -> _Work:
        key = (group, dt)
        if key not in self._work:
            self._work[key] = _Work(plant._matrices(dt), b, self._augmented if self._whole else None)
        return self._work[key]

    def _advance_group(self, group: int, plant: RobotinoPlant, rows: np.ndarray, U: np.ndarray, dt: float,
                       peaks: np.ndarray) -> None:
        """`advance` of one parameter group (rows `rows` of the batch), its peak currents into `peaks` (3, B)."""
        c = plant._matrices(dt)
        n, b = c.n, len(rows)
        work = self._work_of(group, plant, dt, b)
        w, trace = work.augmented, work.trace
        if self._whole:
            w[12:] = U.T
        else:
            w[:12], w[12:] = self._columns[:, rows], U[rows].T
        np.matmul(work.rows, w, out=work.heading)
        eps, beta = work.eps, work.beta
        start, end, theta_end = work.ends
        trace[:n, _HELD] = w[12:]
        # Into each run's start frame: the loop vector (rotated planar pairs, then w[5:12])
        _rotate(w[:4].reshape(2, 2, b), np.cos(start, out=work.cos), np.sin(start, out=work.sin),
                trace[0, _PLANAR].reshape(2, 2, b), work.scratch, 1.0)
        trace[0, _THETA_RATE:] = w[5:12]
        turn = float(np.abs(eps, out=work.turns).max())  # the step's largest |eps / eps_max|
        slow = np.empty(0, dtype=np.intp)
        if c.coefficients is None:
            slow = np.arange(b)
        elif turn > 1.0:  # the runs beyond the fit take the exact maps
            each = np.abs(eps).max(axis=0)
            slow = np.flatnonzero(each > 1.0)
            turn = float(each[each <= 1.0].max(initial=0.0))
        if len(slow) < b:
            maps = self._stacked_maps(group, plant, dt)
            degree = self._degree((group, dt), turn)
            matrix = maps[degree]
            # the basis (1, e, .., e^J, beta) of each substep, e = eps / eps_max (`_EXPONENTS`): (J + 2, n, b)
            basis = work.basis[: degree + 2]
            for j in range(1, degree + 1):
                np.multiply(basis[j - 1], eps, out=basis[j])
            basis[degree + 1] = beta
            products = work.products[: len(matrix)]
            terms = products.reshape(degree + 2, len(_ROWS), b)
            for k in range(n):
                np.matmul(matrix, trace[k, _MOVED], out=products)
                np.einsum("jib,jb->ib", terms, basis[:, k], out=trace[k + 1, _LOOP])
                trace[k + 1, _WHEEL_ROWS] += trace[k, _WHEEL_ROWS]  # C_0's identity on them
        means = work.mean_rows @ w[:, slow]  # the substeps' mean headings of the runs on the exact maps
        for column, r in enumerate(slow):  # exact maps, as `RobotinoPlant.step` beyond the fit
            for k in range(n):
                exact = _turn(beta[k, r]) @ plant._substep_map(eps[k, r] * c.eps_max, means[k, column], c.h)
                trace[k + 1, _LOOP, r] = exact @ np.concatenate((trace[k, _LOOP, r], trace[k, _HELD, r]))
        # Back from the end frame: the state (w's first 12 rows, the batch's own when it is one group)
        _rotate(trace[n, _PLANAR].reshape(2, 2, b), np.cos(end, out=work.cos), np.sin(end, out=work.sin),
                w[:4].reshape(2, 2, b), work.scratch, -1.0)
        w[4], w[5:12] = theta_end, trace[n, _THETA_RATE:]
        currents, largest, magnitudes = trace[:, _CURRENT_ROWS], work.largest, work.magnitudes
        np.abs(currents[0], out=largest)
        for k in range(1, n + 1):  # (a reduction over the first axis of (n + 1, 3, b) costs half as much again)
            np.maximum(largest, np.abs(currents[k], out=magnitudes), out=largest)
        if self._whole:
            np.copysign(work.largest, currents[-1], out=peaks)
        else:
            self._columns[:, rows] = w[:12]
            peaks[:, rows] = np.copysign(work.largest, currents[-1])


def _rotate(pairs: np.ndarray, cos: np.ndarray, sin: np.ndarray, out: np.ndarray, scratch: np.ndarray,
            sign: float) -> None:
    """The planar pairs ((x, x'), (y, y')) (2, 2, b) turned by -angle (sign 1) or by angle (sign -1), into `out`.

    cos and sin (b,) are those of the angle: out_x = cos x + sign sin y, out_y = cos y - sign sin x.
    """
    np.multiply(pairs, cos, out=out)
    np.multiply(pairs[::-1], sin, out=scratch)  # sin (y, x)
    (np.add if sign > 0 else np.subtract)(out[0], scratch[0], out=out[0])
    (np.subtract if sign > 0 else np.add)(out[1], scratch[1], out=out[1])


class _Work:
    """The arrays one step of a parameter group writes (one step size, b runs), kept from step to step.

    ``rows`` are the heading rows `PlantBatch` reads of `RobotinoPlant`'s every step (eps / eps_max and beta
    of each substep, the frame angles at the start and end, theta at the end), ``heading`` their product with
    the augmented states ``augmented`` (15, b), ``mean_rows`` those of the substeps' mean headings (read only
    for the exact maps); ``trace`` (n + 1, 14, b) the loop vectors at the substep ends with the held voltages
    first (`_HELD`, `_LOOP`).
    """

    def __init__(self, c: _StepCache, b: int, augmented: np.ndarray | None) -> None:
        n = c.n
        picked = [*range(1, n * _BASIS, _BASIS), *range(_BASIS - 1, n * _BASIS, _BASIS),
                  *range(n * _BASIS, n * _BASIS + 3)]
        self.rows = np.ascontiguousarray(c.heading_rows[picked])
        self.mean_rows = c.heading_rows[n * _BASIS + 3 :]
        self.heading = np.empty((len(picked), b))
        self.eps, self.beta, self.ends = self.heading[:n], self.heading[n : 2 * n], self.heading[2 * n :]
        self.augmented = np.zeros((15, b)) if augmented is None else augmented
        self.trace = np.empty((n + 1, 14, b))
        self.basis = np.empty((_BASIS, n, b))
        self.basis[0] = 1.0
        self.products = np.empty((_BASIS * len(_ROWS), b))
        self.cos, self.sin, self.scratch = np.empty(b), np.empty(b), np.empty((2, 2, b))
        self.turns, self.magnitudes, self.largest = np.empty((n, b)), np.empty((3, b)), np.empty((3, b))
