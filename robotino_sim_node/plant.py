"""Plant integration core: the coupled Robotino (body, eqs. 1-9; DC drives, eq. 10) under held voltages.

No rclpy here; `plant_node.py` wraps it. The right-hand side is
`robotino_geom_mpc.core.model.coupled_rhs`; this module integrates it with the
armature voltages held over each step (zero-order hold), exactly for the stiff
electrical mode (L / R = 1.5 ms against a 10 ms control period).

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
   d_i(theta) = R(-theta) d_i(0), in that frame the drive directions are
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

import numpy as np
from scipy.linalg import expm

from robotino_geom_mpc.core.model import A_matrix, N_PLANT, g_theta, wheel_directions, wheel_rim_speeds
from robotino_geom_mpc.core.params import RobotinoParams

__all__ = ["PlantError", "RobotinoPlant", "MAX_SUBSTEP_S"]

MAX_SUBSTEP_S = 2.5e-3  # automatic substeps: 4 per 10 ms control period
_CACHE_SIZE = 16  # step sizes whose matrices are kept

# Augmented state w (15): the plant state (9), the wheel angles (3), the held voltages (3).
_N_AUG = 15
_THETA = 4
# A substep maps the loop vector (planar positions and velocities in the frame, theta', currents,
# wheel angles, held voltages) to its first 11 entries; theta comes from the heading rows.
_COLS = np.array([0, 1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14])
_ROWS = _COLS[:11]
_CURRENTS = slice(5, 8)  # of the loop vector
# Generator of a frame rotation acting on (x, y) and (x', y'): d/d(angle) of R(angle) per pair.
_TURN = np.zeros((_N_AUG, _N_AUG))
_TURN[[2, 3], [0, 1]] = 1.0
_TURN[[0, 1], [2, 3]] = -1.0
_FIT_RATE_RAD_S = 20.0
_FIT_DEGREE = 6
_POWERS = np.arange(_FIT_DEGREE + 1)


class PlantError(ValueError):
    """A bad input of the plant (voltages, step size, state, noise), named in the message."""


@dataclass(frozen=True)
class _StepCache:
    """Matrices and work arrays of one step size: n substeps of length h."""

    n: int
    h: float
    eps_max: float  # fit range of the heading change per substep
    # (3n + 2, 15): w -> eps / eps_max (n), frame hand-over angles beta (n - 1), the frame
    # angles at the step's start and end (2), theta at the end (1), the mean headings (n).
    heading_rows: np.ndarray
    coefficients: np.ndarray | None  # (8, 11 * 14): maps in powers of eps / eps_max, then the beta term
    basis: np.ndarray  # (n, 8): powers of eps / eps_max, beta
    powers: np.ndarray  # view of its powers
    trace: np.ndarray  # (n + 1, 14): the loop vectors at the substep ends
    before: list[np.ndarray]  # views of trace: substep inputs
    after: list[np.ndarray]  # and outputs


def _turn(angle: float) -> np.ndarray:
    """(11, 11) rotation of the planar pairs of the loop vector's first 11 entries by angle."""
    c, s = math.cos(angle), math.sin(angle)
    out = np.eye(len(_ROWS))
    out[0, 0] = out[1, 1] = out[2, 2] = out[3, 3] = c
    out[2, 0] = out[3, 1] = s
    out[0, 2] = out[1, 3] = -s
    return out


def _rotate(w: np.ndarray, angle: float) -> None:
    """Rotate the planar pairs (x, y) and (x', y') of w by angle, in place."""
    c, s = math.cos(angle), math.sin(angle)
    x, vx, y, vy = w[:4].tolist()
    w[:4] = (c * x - s * y, c * vx - s * vy, s * x + c * y, s * vx + c * vy)


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
    The equations are `core.model.coupled_rhs`: eq. (1) with the input field
    g(theta) of eq. (9) (erratum 1), wheel forces F = gear Km i / r
    (erratum 4) and the drives L i' = U - R i - Km omega_motor (eq. 10),
    omega_motor = gear (rim speed) / r.
    """

    def __init__(
        self,
        p: RobotinoParams,
        state0: np.ndarray | None = None,
        substeps: int | None = None,
        seed: int | None = 0,
    ) -> None:
        if substeps is not None and (
            isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1
        ):
            raise PlantError(f"substeps must be a positive integer or None, got {substeps!r}")
        self.params = p
        self.substeps = None if substeps is None else int(substeps)
        self.isotropic = p.k_x == p.k_y
        self._rng = np.random.default_rng(seed)
        self._cache: dict[float, _StepCache] = {}
        self._w = np.zeros(_N_AUG)
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
            turn = np.array([[c, -s], [s, c]])
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
        heading_rows = np.vstack(
            (
                eps / eps_max,
                offset[1:] - offset[:-1],
                ends[0] + offset[0],
                ends[n] + offset[n - 1],
                ends[n],
                means,
            )
        )
        coefficients = None
        if self.isotropic:
            nodes = eps_max * np.cos(np.pi * (np.arange(_FIT_DEGREE + 1) + 0.5) / (_FIT_DEGREE + 1))
            samples = np.array([self._substep_map(e, 0.0, h).ravel() for e in nodes])
            powers = np.linalg.solve(np.vander(nodes / eps_max, _FIT_DEGREE + 1, increasing=True), samples)
            # Hand-over to the next frame, turned by a small beta: (I + beta TURN) M, first order in beta.
            handover = (_TURN[np.ix_(_ROWS, _ROWS)] @ self._substep_map(0.0, 0.0, h)).ravel()
            coefficients = np.vstack((powers, handover))
        trace = np.zeros((n + 1, len(_COLS)))
        before, after = list(trace[:-1]), [row[: len(_ROWS)] for row in trace[1:]]
        basis = np.zeros((n, _FIT_DEGREE + 2))
        if len(self._cache) >= _CACHE_SIZE:
            self._cache.clear()
        cache = _StepCache(
            n, h, eps_max, heading_rows, coefficients, basis, basis[:, : _FIT_DEGREE + 1], trace, before, after
        )
        self._cache[dt] = cache
        return cache

    # ------------------------------------------------------------------ integration

    def step(self, voltages: np.ndarray, dt: float) -> None:
        """Advance by dt [s] with the armature voltages U (3,) [V] held constant.

        Raises
        ------
        PlantError
            If `voltages` is not three finite numbers or `dt` is not a positive finite number.
        """
        try:
            U = np.asarray(voltages, dtype=float)
        except (TypeError, ValueError):
            U = np.empty(0)
        if U.shape != (3,) or not math.isfinite(U[0] + U[1] + U[2]):
            raise PlantError(f"voltages must be three finite numbers, got {voltages!r}")
        number = isinstance(dt, (float, int, np.integer)) and not isinstance(dt, bool)
        if not number or not math.isfinite(dt) or dt <= 0.0:
            raise PlantError(f"dt must be a positive finite number of seconds, got {dt!r}")
        c = self._matrices(float(dt))
        w, trace, n = self._w, c.trace, c.n
        w[12:15] = U
        heading = c.heading_rows @ w
        scaled_eps, beta = heading[:n], heading[n : 2 * n - 1]
        start_angle, end_angle, theta_end = heading[2 * n - 1 : 2 * n + 2].tolist()
        basis = c.basis
        np.power(scaled_eps[:, None], _POWERS, out=c.powers)
        basis[:-1, -1] = beta
        if c.coefficients is not None and max(map(abs, scaled_eps.tolist())) <= 1.0:
            maps = (basis @ c.coefficients).reshape(n, len(_ROWS), len(_COLS))
        else:
            maps = np.array(
                [
                    _turn(b) @ self._substep_map(e * c.eps_max, m, c.h)
                    for e, m, b in zip(scaled_eps, heading[2 * n + 2 :], basis[:, -1])
                ]
            )
        _rotate(w, start_angle)
        w.take(_COLS, out=c.before[0])
        trace[1:, len(_ROWS) :] = U
        for substep_map, before, after in zip(maps, c.before, c.after):
            np.dot(substep_map, before, out=after)
        w[_ROWS] = trace[n, : len(_ROWS)]
        w[_THETA] = theta_end
        _rotate(w, -end_angle)
        self._trace = trace
        self._time_s += dt

    def reset(self, state0: np.ndarray | None = None) -> None:
        """Back to `state0` (zeros if None) at time 0 with zero wheel angles."""
        state = np.zeros(N_PLANT) if state0 is None else np.array(state0, dtype=float)
        if state.shape != (N_PLANT,) or not np.isfinite(state).all():
            raise PlantError(f"state0 must be {N_PLANT} finite numbers, got {state0!r}")
        self._w[:] = 0.0
        self._w[:N_PLANT] = state
        self._trace = self._w[None, _COLS]  # the peak currents before any step are |i(0)|
        self._time_s = 0.0

    # ------------------------------------------------------------------ measurements

    @property
    def state(self) -> np.ndarray:
        """(x, x', y, y', theta, theta', i_1, i_2, i_3), a copy."""
        return self._w[:N_PLANT].copy()

    @property
    def pose(self) -> np.ndarray:
        """(x, y, theta) [m, m, rad], a copy."""
        return self._w[0:5:2].copy()

    @property
    def body_state(self) -> np.ndarray:
        """X = (x, x', y, y', theta, theta') of eq. (2)."""
        return self._w[:6].copy()

    @property
    def currents(self) -> np.ndarray:
        """Armature currents i_1..3 [A]."""
        return self._w[6:9].copy()

    @property
    def peak_abs_currents(self) -> np.ndarray:
        """max |i| per drive over the substep ends of the last step and its start [A]."""
        return np.abs(self._trace[:, _CURRENTS]).max(axis=0)

    @property
    def wheel_angles(self) -> np.ndarray:
        """Integrated wheel angles (rim distance / r) since the last reset [rad]."""
        return self._w[9:12].copy()

    @property
    def wheel_speeds(self) -> np.ndarray:
        """Wheel angular velocities, rim speed / r [rad/s] (the motors turn gear times faster)."""
        w = self._w
        return wheel_rim_speeds(w[4], w[[1, 3, 5]], self.params) / self.params.r

    @property
    def time_s(self) -> float:
        """Simulated time since the last reset [s]."""
        return self._time_s

    def odometry(
        self, rng: np.random.Generator | None = None, noise_std: tuple[float, float] = (0.0, 0.0)
    ) -> tuple[np.ndarray, np.ndarray]:
        """A measurement: pose with Gaussian noise, and the noise-free body-frame twist.

        Parameters
        ----------
        rng
            Generator of the noise; the plant's own (seeded) one if None.
        noise_std
            (position [m], angle [rad]) standard deviations, added to x, y and theta.

        Returns
        -------
        pose
            (x, y, theta) + noise.
        twist_body
            (v_x, v_y, theta') in the robot frame (as nav_msgs/Odometry's
            twist): the odom-frame velocity rotated by -theta; noise-free.
        """
        try:
            std_pos, std_angle = (float(v) for v in noise_std)
        except (TypeError, ValueError):
            raise PlantError(f"noise_std must be two non-negative numbers (m, rad), got {noise_std!r}") from None
        if not (std_pos >= 0.0 and std_angle >= 0.0 and math.isfinite(std_pos + std_angle)):
            raise PlantError(f"noise_std must be two non-negative numbers (m, rad), got {noise_std!r}")
        x, vx, y, vy, theta, w = self._w[:6].tolist()
        pose = np.array((x, y, theta))
        if std_pos or std_angle:
            pose += (rng if rng is not None else self._rng).normal(0.0, (std_pos, std_pos, std_angle))
        c, s = math.cos(theta), math.sin(theta)
        twist = np.array((c * vx + s * vy, -s * vx + c * vy, w))
        return pose, twist
