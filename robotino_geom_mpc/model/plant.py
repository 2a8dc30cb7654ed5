"""Plant integration core: the coupled Robotino (body, eqs. 1-9; DC drives, eq. 10) under held voltages.

No rclpy here; `plant_node.py` wraps it. The equations are those of `model.dynamics.coupled_rhs`, with the
armature voltages held over each step (zero-order hold). They are not integrated by calling that function,
which would need a numerical ODE step: they are linear in the state once the heading is fixed, so this module
assembles them as matrices
(`RobotinoPlant._frame_matrix`, from the same `A_matrix`, `g_theta` and wheel
directions) and propagates their exact transition matrices, exact for the
stiff electrical mode (L / R = 1.5 ms against a 10 ms control period).
test/test_plant.py checks those matrices against `coupled_rhs` state by state
and the integration against a DOP853 solution of `coupled_rhs`.

Scheme
------
1. The heading is exact. theta, theta' and the sum of the currents form a
   linear subsystem of their own: the drive directions sum to zero
   (sum_i d_i(theta) = 0), so the back-EMFs of a translation cancel in the sum
   and the torque l sum F_i only sees the summed current. theta at any time
   of the step is a fixed linear function of the state and the held voltages.
2. Each step is cut into `substeps` substeps of length h. On substep k the
   plane is described in a frame turning at the constant rate eps_k / h,
   eps_k the exact heading change over the substep, offset so that the
   heading minus the frame angle averages to zero over the substep. Because
   d_i(theta) = R(theta) d_i(0) (REP-103), in that frame the drive directions are
   d_i(0) up to the (zero-mean, O(h^2 theta'')) deviation, and the frame's
   rotation adds the constant Coriolis term rate * S. The frozen system is
   linear time-invariant; its exact transition matrix expm(A h + eps K)
   (state, wheel angles and held voltages in one augmented matrix) is
   propagated, and the state is handed to the next substep's frame by the
   small offset change. The stiff electrical mode is thus integrated exactly
   and only the deviation of the heading from its linear interpolation is
   approximated (third order per substep, with a zero-mean error).
3. Fast path (k_x == k_y: friction does not depend on the frame): the
   transition matrix depends on eps alone and is a degree-6 polynomial in eps
   (fitted at Chebyshev nodes up to a turn rate of 20 rad/s; entries within
   1e-14 of expm) computed once per step size, so a substep is one small matrix-vector
   product. Beyond that rate, or with k_x != k_y (friction fixed in the odom
   frame, eq. 3, is frame-dependent; it is frozen at the substep's mean
   heading), the transition matrix is computed by expm at each substep:
   correct, about 50 times slower. Step sizes are cached: a new dt costs a
   few expm calls once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import expm

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.model.dynamics import A_matrix, N_PLANT, g_theta, wheel_directions, wheel_rim_speeds
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = ["PlantError", "RobotinoPlant", "MAX_SUBSTEP_S"]

MAX_SUBSTEP_S = 2.5e-3  # automatic substeps: 4 per 10 ms control period
_CACHE_SIZE = 16  # step sizes whose matrices are kept
# The constant matrices of (params, substeps, dt), shared by this process's plants (a study builds one per run).
_SHARED: dict[tuple[RobotinoParams, int | None, float], tuple] = {}

# Augmented state w (15): the plant state (9), the wheel angles (3), the held voltages (3).
_N_AUG = 15
_THETA = 4
# A substep maps the loop vector (planar positions and velocities in the frame, theta', currents,
# wheel angles, held voltages) to its first 11 entries; theta comes from the heading rows.
_COLS = np.array([0, 1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14])
_ROWS = _COLS[:11]
_CURRENTS = slice(5, 8)  # of the loop vector
_N_LOOP = len(_COLS)
# Rows appended to a substep map so that it also passes the held voltages on: (3, 14) [0 | I].
_PASS = np.eye(_N_LOOP)[len(_ROWS) :]
# Generator of a turn of the frame on the coordinates of (x, y) and (x', y') in it: d/d(angle) of
# R(angle)^T per pair (a frame turned by angle sees a vector turned by -angle).
_TURN = np.zeros((_N_AUG, _N_AUG))
_TURN[[2, 3], [0, 1]] = -1.0
_TURN[[0, 1], [2, 3]] = 1.0
_FLOAT64 = np.dtype(np.float64)
_FIT_RATE_RAD_S = 20.0
_FIT_DEGREE = 6
# Exponents of a substep's heading entries (eps / eps_max seven times, beta): its basis row.
_EXPONENTS = np.append(np.arange(_FIT_DEGREE + 1.0), 1.0)
_BASIS = _FIT_DEGREE + 2


class PlantError(RobotinoError, ValueError):
    """A bad input of the plant (voltages, step size, state, noise), named in the message."""


@dataclass(frozen=True)
class _StepCache:
    """Matrices and work arrays of one step size: n substeps of length h."""

    n: int
    h: float
    eps_max: float  # fit range of the heading change per substep
    # (9n + 3, 15): w -> per substep, eps / eps_max seven times and the frame hand-over angle beta
    # (0 on the last) (8n), the frame angles at the step's start and end and theta at the end (3),
    # the mean headings (n). Raised elementwise to `_EXPONENTS`, the first 8n give the basis.
    heading_rows: np.ndarray
    heading: np.ndarray  # (9n + 3,) its product with w
    heading_basis: np.ndarray  # (n, 8) view of its first 8n entries
    coefficients: np.ndarray | None  # (8, 14 * 14): maps in powers of eps / eps_max, then the beta term
    basis: np.ndarray  # (n, 8): powers of eps / eps_max, beta
    maps: np.ndarray  # (n, 14 * 14): the substep maps (with the `_PASS` rows), flat
    substep_maps: list[np.ndarray]  # (14, 14) views of maps
    trace: np.ndarray  # (n + 1, 14): the loop vectors at the substep ends
    before: list[np.ndarray]  # views of trace: substep inputs
    after: list[np.ndarray]  # and outputs


def _turn(angle: float) -> np.ndarray:
    """(11, 11): the loop vector's first 11 entries in a frame turned by angle (planar pairs by R(angle)^T)."""
    c, s = math.cos(angle), math.sin(angle)
    out = np.eye(len(_ROWS))
    out[0, 0] = out[1, 1] = out[2, 2] = out[3, 3] = c
    out[2, 0] = out[3, 1] = -s
    out[0, 2] = out[1, 3] = s
    return out


def _voltage_values(voltages: Any) -> tuple[float, float, float]:
    """The voltages as three Python floats, or PlantError; plain tuples, lists and float arrays fast."""
    kind = type(voltages)
    if (kind is tuple or kind is list) and len(voltages) == 3 and type(voltages[0]) is float \
            and type(voltages[1]) is float and type(voltages[2]) is float:
        U = tuple(voltages)
    elif kind is np.ndarray and voltages.dtype is _FLOAT64 and voltages.shape == (3,):
        U = tuple(voltages.tolist())
    else:
        try:
            array = np.asarray(voltages, dtype=float)
        except (TypeError, ValueError):
            array = np.empty(0)
        U = tuple(array.tolist()) if array.shape == (3,) else ()
    if len(U) != 3 or not math.isfinite(U[0] + U[1] + U[2]):
        raise PlantError(f"voltages must be three finite numbers, got {voltages!r}")
    return U


class RobotinoPlant:
    """The simulated Robotino: coupled body and drives, integrated under held wheel voltages.

    Parameters
    ----------
    p
        Physical parameters of the simulated robot (pass different ones than
        the controller's for mismatch studies).
    state0
        Initial (x, x', y, y', theta, theta', i_1, i_2, i_3); zeros if None.
    substeps
        Substeps per `step` (see the module docstring); None: as many as keep
        them at most `MAX_SUBSTEP_S` long (4 per 10 ms). Against a
        1e-11-tolerance reference, 4 substeps per 10 ms keep the errors at
        about 1e-8 m and 3e-7 A with random +-12 V steps and the robot
        spinning at 3 rad/s (test/test_plant.py); each doubling of the
        substeps cuts them about tenfold. Substeps much longer than
        `MAX_SUBSTEP_S` lose accuracy.
    seed
        Seed of the generator `odometry` uses when given no `rng`.

    Notes
    -----
    The equations are `model.dynamics.coupled_rhs`: eq. (1) with the input field
    g(theta) of eq. (9) (erratum 1), wheel forces F = gear Km i / r
    (erratum 4) and the drives L i' = U - R i - Km omega_motor (eq. 10),
    omega_motor = gear (rim speed) / r.
    """

    def __init__(
        self, p: RobotinoParams, state0: np.ndarray | None = None, substeps: int | None = None, seed: int | None = 0
    ) -> None:
        if substeps is not None and (isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer))
                                     or substeps < 1):
            raise PlantError(f"substeps must be a positive integer or None, got {substeps!r}")
        self.params = p
        self.substeps = None if substeps is None else int(substeps)
        self.isotropic = p.k_x == p.k_y
        self._rng = np.random.default_rng(seed)
        self._cache: dict[float, _StepCache] = {}
        self.reset(state0)

    # ------------------------------------------------------------------ model matrices

    def _frame_matrix(self, rate: float, frame_angle: float) -> np.ndarray:
        """Augmented state matrix (w' = A w) in a frame turning at `rate` [rad/s], heading on the frame.

        Planar positions and velocities are in the frame; the drive directions
        are d_i(0). `frame_angle` only orients anisotropic friction.
        """
        p = self.params
        # gear Km / r: wheel force per ampere [N/A] and back-EMF per rim speed [V s/m].
        k_wheel = p.gear_ratio * p.torque_constant_n_m_per_a / p.r
        d = wheel_directions(0.0)
        rim = np.zeros((3, N_PLANT))  # rim speeds of the wheels from the state
        rim[:, 1], rim[:, 3], rim[:, 5] = d[:, 0], d[:, 1], p.l
        A = np.zeros((_N_AUG, _N_AUG))
        A[0:6, 0:6] = A_matrix(p)
        if not self.isotropic:
            c, s = math.cos(frame_angle), math.sin(frame_angle)
            turn = np.array([[c, s], [-s, c]])  # odom -> frame coordinates
            A[np.ix_([1, 3], [1, 3])] = -turn @ np.diag([p.k_x, p.k_y]) @ turn.T / p.M
        A[0:6, 6:9] = k_wheel * g_theta(0.0, p)
        A[6:9, :N_PLANT] = -k_wheel / p.inductance_h * rim
        A[6:9, 6:9] -= p.resistance_ohm / p.inductance_h * np.eye(3)
        A[6:9, 12:15] = np.eye(3) / p.inductance_h
        A[9:12, :N_PLANT] = rim / p.r
        return A + rate * _TURN

    def _substep_map(self, eps: float, frame_angle: float, h: float) -> np.ndarray:
        """(11, 14): the loop vector at the start of a substep -> its first 11 entries at the end."""
        return expm(self._frame_matrix(eps / h, frame_angle) * h)[np.ix_(_ROWS, _COLS)]

    def _matrices(self, dt: float) -> _StepCache:
        cache = self._cache.get(dt)
        if cache is not None:
            return cache
        key = (self.params, self.substeps, dt)
        if key not in _SHARED:
            if len(_SHARED) >= _CACHE_SIZE:
                _SHARED.clear()
            _SHARED[key] = self._constant_matrices(dt)
        n, h, eps_max, heading_rows, coefficients = _SHARED[key]
        trace, maps, heading = np.zeros((n + 1, _N_LOOP)), np.zeros((n, _N_LOOP * _N_LOOP)), np.zeros(len(heading_rows))
        if len(self._cache) >= _CACHE_SIZE:
            self._cache.clear()
        cache = _StepCache(
            n, h, eps_max, heading_rows, heading, heading[: n * _BASIS].reshape(n, _BASIS), coefficients,
            np.zeros((n, _BASIS)), maps, list(maps.reshape(n, _N_LOOP, _N_LOOP)), trace, list(trace[:-1]),
            list(trace[1:]),
        )
        self._cache[dt] = cache
        return cache

    def _constant_matrices(self, dt: float) -> tuple[int, float, float, np.ndarray, np.ndarray | None]:
        """(n, h, eps_max, heading_rows, coefficients) of `_StepCache` for a step of dt: the expm calls."""
        n = self.substeps or max(1, math.ceil(dt / MAX_SUBSTEP_S - 1e-9))
        h = dt / n
        eps_max = _FIT_RATE_RAD_S * h
        # theta at t_k and its mean over [t_k, t_k + h] (frame-independent), the latter
        # through an extra state integrating theta.
        A = np.zeros((_N_AUG + 1, _N_AUG + 1))
        A[:_N_AUG, :_N_AUG] = self._frame_matrix(0.0, 0.0)
        A[_N_AUG, _THETA] = 1.0
        transition = expm(A * h)
        step = transition[:_N_AUG, :_N_AUG]
        ends, means = np.empty((n + 1, _N_AUG)), np.empty((n, _N_AUG))
        ends[0], means[0] = np.eye(_N_AUG)[_THETA], transition[_N_AUG, :_N_AUG] / h
        for k in range(n):
            ends[k + 1] = ends[k] @ step
            if k + 1 < n:
                means[k + 1] = means[k] @ step
        # The frame of substep k starts at ends[k] + offset[k] and turns by eps[k].
        eps = ends[1:] - ends[:-1]
        offset = means - 0.5 * (ends[1:] + ends[:-1])
        beta = np.vstack((offset[1:] - offset[:-1], np.zeros(_N_AUG)))
        per_substep = np.concatenate((np.repeat(eps[:, None] / eps_max, _FIT_DEGREE + 1, axis=1), beta[:, None]), 1)
        heading_rows = np.vstack(
            (per_substep.reshape(n * _BASIS, _N_AUG), ends[0] + offset[0], ends[n] + offset[n - 1], ends[n], means)
        )
        coefficients: np.ndarray | None = None
        if self.isotropic:
            nodes = eps_max * np.cos(np.pi * (np.arange(_FIT_DEGREE + 1) + 0.5) / (_FIT_DEGREE + 1))
            samples = np.array([self._substep_map(e, 0.0, h).ravel() for e in nodes])
            powers = np.linalg.solve(np.vander(nodes / eps_max, _FIT_DEGREE + 1, increasing=True), samples)
            # Hand-over to the next frame, turned by a small beta: (I + beta TURN) M, first order in beta.
            handover = (_TURN[np.ix_(_ROWS, _ROWS)] @ self._substep_map(0.0, 0.0, h)).ravel()
            # The voltages pass through the constant term (eps^0 = 1) only.
            coefficients = np.zeros((_BASIS, _N_LOOP, _N_LOOP))
            coefficients[:, : len(_ROWS)] = np.vstack((powers, handover)).reshape(_BASIS, len(_ROWS), _N_LOOP)
            coefficients[0, len(_ROWS) :] = _PASS
            coefficients = coefficients.reshape(_BASIS, _N_LOOP * _N_LOOP)
        return n, h, eps_max, heading_rows, coefficients

    # ------------------------------------------------------------------ integration

    def step(self, voltages: np.ndarray, dt: float) -> None:
        """Advance by dt [s] with the armature voltages U (3,) [V] held constant.

        Raises
        ------
        PlantError
            If `voltages` is not three finite numbers or `dt` is not a positive finite number.

        Notes
        -----
        Written for numpy's per-call overhead (it dominates on these sizes):
        one product gives every heading quantity of the step, one power the
        polynomial basis, one product the substep maps, then one product per
        substep; the frame rotations are done on Python floats.
        """
        U = _voltage_values(voltages)
        c = self._cache.get(dt) if type(dt) is float else None  # only valid step sizes are cached
        if c is None:
            number = isinstance(dt, (float, int, np.integer)) and not isinstance(dt, bool)
            if not number or not math.isfinite(dt) or dt <= 0.0:
                raise PlantError(f"dt must be a positive finite number of seconds, got {dt!r}")
            c = self._matrices(float(dt))
        n = c.n
        w = self._w + list(U)  # the augmented state w
        heading = c.heading_rows.dot(w, c.heading)
        values = heading.tolist()
        start_angle, end_angle, theta_end = values[n * _BASIS : n * _BASIS + 3]
        scaled_eps = values[1 : n * _BASIS : _BASIS]
        if c.coefficients is not None and max(map(abs, scaled_eps)) <= 1.0:
            np.power(c.heading_basis, _EXPONENTS, out=c.basis)
            c.basis.dot(c.coefficients, c.maps)
            maps = c.substep_maps
        else:
            maps = [
                np.vstack((_turn(b) @ self._substep_map(e * c.eps_max, m, c.h), _PASS))
                for e, b, m in zip(scaled_eps, values[_BASIS - 1 : n * _BASIS : _BASIS], values[n * _BASIS + 3 :])
            ]
        # Into the start frame (loop vector: rotated planar pairs, then w[5:]), through the substeps, back.
        x, vx, y, vy, _, *rest = w
        cos, sin = math.cos(-start_angle), math.sin(-start_angle)
        c.before[0][:] = (cos * x - sin * y, cos * vx - sin * vy, sin * x + cos * y, sin * vx + cos * vy, *rest)
        for substep_map, before, after in zip(maps, c.before, c.after):
            substep_map.dot(before, after)
        x, vx, y, vy, *rest = c.after[-1].tolist()[: len(_ROWS)]
        cos, sin = math.cos(end_angle), math.sin(end_angle)
        self._w: list[float] = [cos * x - sin * y, cos * vx - sin * vy, sin * x + cos * y, sin * vx + cos * vy,
                                theta_end, *rest]
        self._trace = c.trace
        self._time_s += dt

    def reset(self, state0: np.ndarray | None = None) -> None:
        """Back to `state0` (zeros if None) at time 0 with zero wheel angles."""
        state = np.zeros(N_PLANT) if state0 is None else checked_array(state0, (N_PLANT,), "state0", PlantError)
        self._w = state.tolist() + [0.0, 0.0, 0.0]  # w without the voltages, as floats
        self._trace = np.zeros((1, _N_LOOP))
        self._trace[0, _CURRENTS] = state[6:9]  # the peak currents before any step are |i(0)|
        self._time_s: float = 0.0

    # ------------------------------------------------------------------ measurements

    @property
    def state(self) -> np.ndarray:
        """(x, x', y, y', theta, theta', i_1, i_2, i_3), a copy."""
        return np.array(self._w[:N_PLANT])

    @property
    def pose(self) -> list[float]:
        """(x, y, theta) [m, m, rad] as a new list of three Python floats (the offline loop's per-tick record)."""
        return self._w[0:5:2]

    @property
    def body_state(self) -> np.ndarray:
        """X = (x, x', y, y', theta, theta') of eq. (2)."""
        return np.array(self._w[:6])

    @property
    def currents(self) -> np.ndarray:
        """Armature currents i_1..3 [A]."""
        return np.array(self._w[6:9])

    @property
    def peak_abs_currents(self) -> np.ndarray:
        """max |i| per drive over the substep ends of the last step and its start [A]."""
        return np.abs(self._trace[:, _CURRENTS]).max(axis=0)

    @property
    def substep_currents(self) -> np.ndarray:
        """(substeps + 1, 3): the currents at the start of the last step and at its substep ends [A], a copy.

        Before any step, the one row i(0). `peak_abs_currents` is the largest |entry| of each column.
        """
        return self._trace[:, _CURRENTS].copy()

    @property
    def wheel_angles(self) -> np.ndarray:
        """Integrated wheel angles (rim distance / r) since the last reset [rad]."""
        return np.array(self._w[9:12])

    @property
    def wheel_speeds(self) -> np.ndarray:
        """Wheel angular velocities, rim speed / r [rad/s] (the motors turn gear times faster)."""
        w = self._w
        return wheel_rim_speeds(w[4], np.array(w[1:6:2]), self.params) / self.params.r

    @property
    def time_s(self) -> float:
        """Simulated time since the last reset [s]."""
        return self._time_s

    def odometry(
        self, rng: np.random.Generator | None = None, noise_std: tuple[float, float] = (0.0, 0.0)
    ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """A measurement: pose with Gaussian noise, and the noise-free body-frame twist (Python floats).

        Parameters
        ----------
        rng
            Generator of the noise; the plant's own (seeded) one if None.
        noise_std
            (position [m], angle [rad]) standard deviations, added to x, y and theta.

        Returns
        -------
        pose, twist_body
            (x, y, theta) + noise; (v_x, v_y, theta') in the robot frame (nav_msgs/Odometry's twist), noise-free.
        """
        return self.noisy_odometry(self.pose_noise(rng, noise_std))

    def noisy_odometry(
        self, noise: tuple[float, float, float] | None
    ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """`odometry` with the pose noise (x, y, theta) given, None: none (noise drawn ahead, unchecked)."""
        x, vx, y, vy, theta, w = self._w[:6]
        c, s = math.cos(theta), math.sin(theta)
        twist = (c * vx + s * vy, -s * vx + c * vy, w)
        if noise is not None:
            nx, ny, ntheta = noise
            return (x + nx, y + ny, theta + ntheta), twist
        return (x, y, theta), twist

    def pose_noise(
        self, rng: np.random.Generator | None, noise_std: tuple[float, float]
    ) -> tuple[float, float, float] | None:
        """The Gaussian pose noise (x, y, theta) of one measurement, None when both std are 0 (nothing drawn).

        Raises
        ------
        PlantError
            If `noise_std` is not two non-negative finite numbers (m, rad).
        """
        try:
            std_pos, std_angle = noise_std
            std_pos, std_angle = float(std_pos), float(std_angle)
        except (TypeError, ValueError):
            raise PlantError(f"noise_std must be two non-negative numbers (m, rad), got {noise_std!r}") from None
        if not (std_pos >= 0.0 and std_angle >= 0.0 and math.isfinite(std_pos + std_angle)):
            raise PlantError(f"noise_std must be two non-negative numbers (m, rad), got {noise_std!r}")
        if std_pos or std_angle:
            return tuple((rng if rng is not None else self._rng).normal(0.0, (std_pos, std_pos, std_angle)).tolist())
        return None
