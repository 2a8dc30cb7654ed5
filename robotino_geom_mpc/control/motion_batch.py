"""`MotionController.step` for B runs at once: the array form of one control step, each run with its own model.

Fig. 3 per run, as arrays with a leading batch axis: the pose filter
(`OdometryFilterBatch.update`), the three MPCs (`DecoupledMPCBatch.delta_u`), the
decoupling field (`DecouplingFieldBatch.forces`), the inverse drive with the
current limit (`InverseDriveBatch.limited_step`) and the anti-windup of
clipped voltages, in the order and with the relations of
`MotionController.step` (see its notes). Closed-form mode, one period per
step (the offline loop's rhythm); the constrained mode's QP stays per run
(`MotionController`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from robotino_geom_mpc.control.estimator import OdometryFilterBatch
from robotino_geom_mpc.control.inverse_drive import InverseDriveBatch
from robotino_geom_mpc.control.mpc import DecoupledMPCBatch, axis_dampings
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.geometric.decoupling import DecouplingFieldBatch
from robotino_geom_mpc.model.dynamics import acceleration_blocks, force_per_current
from robotino_geom_mpc.model.kinematics import MotorKinematicsBatch
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams

__all__ = ["BatchControlError", "MotionControllerBatch"]


class BatchControlError(RobotinoError, ValueError):
    """A batch the array form cannot step (the constrained mode, no runs, mismatched sizes)."""


class MotionControllerBatch:
    """B closed-form controllers (eqs. 48-56, 33-37, 10) stepped together.

    Parameters
    ----------
    robots
        Each run's controller model (B of them).
    control
        The settings every run shares (closed-form mode).
    twists
        Each run's odometry twist model (the pose filter's predictor, `TWIST_MODELS`).
    start
        The poses (B, 3) where robot and reference start together (`MotionController.start_at`).
    """

    def __init__(self, robots: Sequence[RobotinoParams], control: ControlParams, twists: Sequence[str],
                 start: np.ndarray) -> None:
        if control.mode != "closed_form":
            raise BatchControlError(f"the batched controller is closed-form only, got mode {control.mode!r}")
        if not robots or len(twists) != len(robots):
            raise BatchControlError(f"need one twist model per run and at least one run, got {len(robots)} runs "
                                    f"and {len(twists)} twist models")
        self.period_s = float(control.period_s)
        self.mpc = DecoupledMPCBatch(robots, control)
        self.field = DecouplingFieldBatch(robots)
        self.kinematics = MotorKinematicsBatch(robots)
        self.drive = InverseDriveBatch(robots, self.period_s)
        self.current_limit_a = float(control.current_limit_a)
        self._damping = np.stack([axis_dampings(p) for p in robots])
        # eq. (9) per run: wheel forces per unit current and the M, l / J of the acceleration rows
        self._force_per_current = np.array([force_per_current(p) for p in robots])[:, None]
        self._mass, self._lever_per_inertia = np.array([p.M for p in robots]), np.array([p.l / p.J for p in robots])
        tau = float(control.odometry_filter_time_constant_s)
        self.estimator = OdometryFilterBatch(self.period_s, tau, twists, start) if tau > 0.0 else None
        self.u_prev = np.zeros((len(robots), 3))

    def _acceleration_of_current(self, theta: np.ndarray, current: np.ndarray) -> np.ndarray:
        """(x'', y'', theta'') the wheel currents (B, 3) give at headings theta (B,), friction aside (eq. 9)."""
        blocks = acceleration_blocks(theta, self._mass, self._lever_per_inertia)
        return (blocks @ (self._force_per_current * current)[:, :, None])[:, :, 0]

    def step(self, X: np.ndarray, preview: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One control period of every run: voltages (B, 3) and the saturated flags (B,).

        Parameters
        ----------
        X
            The measured body states (B, 6) (eq. 2).
        preview
            The reference positions at t + Ts .. t + N Ts, (N, 3) shared or (B, N, 3) per run.
        """
        X = np.array(X, dtype=float)
        if self.estimator is not None:
            X[:, 0::2] = self.estimator.update(X)
        theta, velocity = X[:, 4], X[:, 1::2]
        theta_m = theta + 0.5 * self.period_s * velocity[:, 2]
        u = self.u_prev + self.mpc.delta_u(X, self.u_prev, preview)
        currents = self.drive.current_per_force * self.field.forces(theta_m, u)
        omega, omega_rate = self.kinematics.speeds_and_rates(theta, velocity, u - self._damping * velocity)

        def rate_of_current(current: np.ndarray) -> np.ndarray:
            acceleration = self._acceleration_of_current(theta_m, current) - self._damping * velocity
            return self.kinematics.speeds_and_rates(theta, velocity, acceleration)[1]

        if self.current_limit_a > 0.0:
            voltages, saturated, mean, scale = self.drive.limited_step(
                currents, omega, omega_rate,
                lambda: self.kinematics.speeds_and_rates(theta, velocity, -self._damping * velocity)[1],
                self.current_limit_a, rate_of_current)
            if scale.min() < 1.0:  # (all at 1: u as it is, the same numbers)
                u = scale[:, None] * u
        else:
            voltages, saturated, mean = self.drive.step(currents, omega, omega_rate, rate_of_current)
        # a clipped run keeps the acceleration its mean current gives (anti-windup); the others their u
        self.u_prev = np.where(saturated[:, None], self._acceleration_of_current(theta_m, mean), u) \
            if np.count_nonzero(saturated) else u
        return voltages, saturated
