"""One control step of Fig. 3: three decoupled MPCs -> T(theta) -> inverse DC drive -> wheel voltages.

This is the whole controller the controller node wraps and the offline
simulation calls once per period; it knows nothing of ROS.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from robotino_geom_mpc.control.constrained import ConstrainedMPC
from robotino_geom_mpc.geometric.decoupling import DecouplingField
from robotino_geom_mpc.control.inverse_drive import InverseDrive
from robotino_geom_mpc.model.kinematics import MotorKinematics
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.control.estimator import OdometryFilter
from robotino_geom_mpc.model.dynamics import acceleration_block, wheel_forces
from robotino_geom_mpc.control.mpc import DecoupledMPC, axis_dampings
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams

__all__ = ["ControllerInputError", "ControlOutput", "MotionController", "state_from_odometry", "states_from_odometry",
           "step_interval"]


_FLOAT64 = np.dtype(np.float64)
_FLOAT_TYPE = {float}  # the element types of an X the fast path takes as it is
# a measured state is refused beyond these: no wheel turns faster than its motor's no-load speed at the supply
# voltage, U_supply / Km, unless the robot is pushed; twice that is no measurement of a robot on its wheels
PLAUSIBLE_SPEED_FACTOR = 2.0
MAX_POSITION_M = 1.0e6  # a pose 1000 km from the odom origin is garbage (float resolution there is still 1e-10 m)


class ControllerInputError(RobotinoError, ValueError):
    """A measured state, reference preview or interval with the wrong shape or a non-finite or out-of-range value."""


class ControlOutput(NamedTuple):
    """Result of one control step (immutable; the 3-vectors are tuples of floats).

    Attributes
    ----------
    voltages
        Wheel voltages U_1..3 [V] to hold over the next period, within +-supply.
    currents
        Commanded wheel currents i = F r / (gear Km) [A], F = T(theta) u.
    u
        Commanded accelerations (u_x, u_y, u_theta) of the MPCs (eq. 48), scaled when the current limit binds.
    saturated
        True when a voltage was clipped to the supply.
    infeasible
        True when the constrained mode could not meet its limits (always False in closed form).
    compute_time_s
        Wall-clock time of the step [s].
    """

    voltages: tuple[float, ...]
    currents: tuple[float, ...]
    u: tuple[float, ...]
    saturated: bool
    infeasible: bool
    compute_time_s: float


class MotionController:
    """MPCs (eqs. 48-56) -> decoupling field T(theta) (eqs. 33-37) -> inverse drive (eq. 10).

    Parameters
    ----------
    robot
        The controller's model of the robot.
    control
        Period, horizon, weights, mode (`closed_form` or `constrained`) and the
        time constant of the odometry filter (0 = the measured pose as it is).

    Notes
    -----
    One step, for the measured body state X = (x, x', y, y', theta, theta')
    taken dt after the previous one, and the reference positions
    y_d(k+1) .. y_d(k+N) (at Ts, 2 Ts, ... after that measurement):

    0. with ``control.odometry_filter_time_constant_s`` > 0, the pose (x, y, theta)
       is replaced by its estimate from `estimator.OdometryFilter` (predicted
       with the measured velocity over dt, corrected towards the measured
       pose), so pose noise does not reach u through the MPC's position gain;
       the velocities are used as measured. The drive's start currents are
       predicted over dt as well (`drive.InverseDrive.advance`): the last
       voltages were held until now;
    1. u(k) = u(k-1) + Delta u(k), Delta u(k) the first component of eq. (56)
       (`mpc.DecoupledMPC.delta_u`; or of the constrained QP,
       `constrained.ConstrainedMPC`); the MPC stays discrete at Ts (eq. 49),
       u(k-1) is the input applied last;
    2. wheel forces F = T(theta_m) u(k) (`decoupling.DecouplingField.forces`)
       at the mid-period heading theta_m = theta + theta' Ts / 2 (the
       forces are held while the body turns), currents i = F r / (gear Km);
    3. voltages from `drive.InverseDrive` (eq. 10) with the motor speeds of the
       measured velocity and their rate under the commanded acceleration
       u - (k/M) v, clipped to the supply. When clipped, u(k) is replaced by
       the acceleration the clipped voltages give (anti-windup), so the next
       Delta u starts from what the robot really receives.

    With ``control.current_limit_a`` = I_max > 0 (closed-form mode), step 3
    first scales u(k), hence F and i (linear in u), by one factor s in (0, 1]
    when a wheel's period-average or end-of-period current would exceed I_max
    or its voltage the supply (`drive.InverseDrive.limited_step`): the
    acceleration keeps its direction, the largest wheel sits at its limit, and
    u(k-1) of the next step is s u(k), what was applied (anti-windup). The
    constrained mode keeps its own limits (the QP) and ignores I_max.
    """

    def __init__(self, robot: RobotinoParams, control: ControlParams) -> None:
        self.robot = robot
        self.control = control
        self.period_s = float(control.period_s)
        self.horizon = int(control.horizon)
        self.mpc = DecoupledMPC(robot, control)
        self.field = DecouplingField(robot)
        self.kinematics = MotorKinematics(robot)
        self.max_motor_speed = PLAUSIBLE_SPEED_FACTOR * robot.supply_voltage_v / robot.torque_constant_n_m_per_a
        self.drive = InverseDrive(robot, self.period_s)
        self._damping = axis_dampings(robot)
        self._damping_rates = tuple(self._damping.tolist())
        # rows 2, 4, 6 of g(0) times gear Km / r: (x'', y'', theta'') in base_link per ampere of each wheel
        per_ampere = acceleration_block(0.0, robot) * wheel_forces(np.ones(3), robot)
        self._per_ampere = tuple(map(tuple, per_ampere.tolist()))
        tau = float(control.odometry_filter_time_constant_s)
        self.estimator = OdometryFilter(self.period_s, tau, control.odometry_twist) if tau > 0.0 else None
        self.constrained = ConstrainedMPC(robot, control, self.mpc) if control.mode == "constrained" else None
        self.current_limit_a = float(control.current_limit_a) if self.constrained is None else 0.0
        self.reset()

    def reset(self) -> None:
        """Forget the previous input, the drive's current estimate and the pose estimate (robot at rest, drives off)."""
        self._u_prev = [0.0, 0.0, 0.0]
        self._last: tuple[list[float], list[float], list[list[float]]] | None = None  # x, u(k-1), preview
        self.drive.reset()
        if self.estimator is not None:
            self.estimator.reset()
        if self.constrained is not None:
            self.constrained.reset()

    def restart_from(self, u_prev: list[float], currents: list[float]) -> None:
        """Continue as if the accelerations `u_prev` had been applied in the last period and the drives' currents
        were ``currents`` [A] now (the delay-compensating controller's rollout starts from its prediction).

        The pose filter and the constrained mode's warm start are left as they are.
        """
        self._u_prev = [float(v) for v in u_prev]
        self.drive.reset(np.array(currents, dtype=float))

    def start_at(self, x: float, y: float, theta: float) -> None:
        """Start the pose filter at a known pose of the robot at rest (`OdometryFilter.start_at`), no-op without one.

        For tick 0 of a run, where robot and reference start together: the first measurement's pose noise
        then reaches the MPCs as L n(0), not as a start kick.
        """
        if self.estimator is not None:
            self.estimator.start_at(x, y, theta)

    def _acceleration_of_current(self, theta_m: float, current: Sequence[float]) -> list[float]:
        """Body acceleration (x'', y'', theta'') the wheel currents give (friction aside), eq. (9).

        g(theta) F with F = gear Km i / r, as R(theta) applied to the heading-free sums of `_per_ampere`
        (d_i(theta) = R(theta) d_i(0)): floats, since it runs several times per saturated period.
        """
        (x0, x1, x2), (y0, y1, y2), (w0, w1, w2) = self._per_ampere
        i0, i1, i2 = float(current[0]), float(current[1]), float(current[2])
        bx, by = x0 * i0 + x1 * i1 + x2 * i2, y0 * i0 + y1 * i1 + y2 * i2
        c, s = math.cos(theta_m), math.sin(theta_m)
        return [c * bx - s * by, s * bx + c * by, w0 * i0 + w1 * i1 + w2 * i2]

    def _rate_of_current(self, theta: float, theta_m: float, velocity: tuple[float, float, float],
                         current: Sequence[float]) -> list[float]:
        """Motor-speed rate under the acceleration the currents give (used when the voltage saturates)."""
        ax, ay, aw = self._acceleration_of_current(theta_m, current)
        (vx, vy, w), (dx, dy, dw) = velocity, self._damping_rates
        return self.kinematics.speeds_and_rates(theta, velocity, (ax - dx * vx, ay - dy * vy, aw - dw * w))[1]

    def _check(self, X: object, preview: object) -> tuple[list[float], list[list[float]]]:
        """X and the preview as Python floats, or ControllerInputError naming the bad one.

        A tuple of six floats and a float array of the preview's shape (the offline loop's) skip numpy's conversions.
        """
        if type(X) is tuple and len(X) == 6 and set(map(type, X)) == _FLOAT_TYPE:
            x = list(X)
        else:
            X = np.asarray(X, dtype=float)
            if X.shape != (6,):
                raise ControllerInputError(f"X must have shape (6,), got {X.shape}")
            x = X.tolist()
        Y_d = preview if type(preview) is np.ndarray and preview.dtype is _FLOAT64 else np.asarray(preview, dtype=float)
        if Y_d.shape != (self.horizon, 3):
            raise ControllerInputError(f"preview must have shape ({self.horizon}, 3), got {Y_d.shape}")
        y = Y_d.tolist()
        # A sum is finite iff its terms are, short of overflow (values near 1e308 are garbage too):
        # one sum over both, and the culprit named when it is not finite.
        if not math.isfinite(sum(x) + sum(map(sum, y))):
            if not math.isfinite(sum(x)):
                raise ControllerInputError(f"X must be finite and of physical magnitude, got {x}")
            raise ControllerInputError("preview must be finite and of physical magnitude")
        return x, y

    def state_problem(self, X: np.ndarray) -> str | None:
        """Why a finite measured state X (eq. 2) cannot be the robot's, or None.

        A position beyond `MAX_POSITION_M`, or a velocity that needs a motor speed W(theta) (x', y', theta')
        above `PLAUSIBLE_SPEED_FACTOR` times the no-load speed U_supply / Km. Such a state (a corrupt or
        misscaled odometry) would otherwise drive the controller to full voltage, and a bumpless restart
        would blend in from it for minutes.
        """
        x, vx, y, vy, theta, w = X.tolist()
        if max(abs(x), abs(y)) > MAX_POSITION_M:
            return f"position ({x:.4g}, {y:.4g}) m is beyond {MAX_POSITION_M:g} m"
        speeds = self.kinematics.speeds_and_rates(theta, (vx, vy, w), (0.0, 0.0, 0.0))[0]
        fastest = max(map(abs, speeds))
        if fastest > self.max_motor_speed:
            return (f"velocity ({vx:.4g} m/s, {vy:.4g} m/s, {w:.4g} rad/s) needs a motor speed of {fastest:.4g} rad/s, "
                    f"beyond {PLAUSIBLE_SPEED_FACTOR:g} x the no-load speed U_supply / Km")
        return None

    @staticmethod
    def _interval(dt_s: object) -> float:
        """dt_s (a real number, not a bool or a string) as a float > 0, or ControllerInputError."""
        number = isinstance(dt_s, (float, int, np.floating, np.integer)) and not isinstance(dt_s, bool)
        dt = float(dt_s) if number else math.nan  # type: ignore[arg-type]  # a number, checked just above
        if not (math.isfinite(dt) and dt > 0.0):
            raise ControllerInputError(f"dt_s must be a finite number of seconds > 0 (or None), got {dt_s!r}")
        return dt

    def step(self, X: object, preview: object, dt_s: float | None = None) -> ControlOutput:
        """One control period: voltages for the measured state and the reference preview.

        Parameters
        ----------
        X
            Measured body state (x, x', y, y', theta, theta'), shape (6,), taken at t.
        preview
            Reference positions (x_d, y_d, theta_d) at t + Ts, ..., t + N Ts, shape (N, 3).
        dt_s
            Time [s] since the measurement of the previous step (from the
            measurements' stamps), > 0; None means one period Ts. Any positive
            value is taken: a repeated measurement (dt ~ 1e-9 s) predicts no
            motion and re-solves the MPC from u(k-1) = the input just applied
            (its increment scaled by 1 - k_0 F_2p, 0.39 for the Robotino 3
            preset), a lost one (2 Ts) the motion over both periods. Ignored
            by the first step after construction or `reset`.

        Returns
        -------
        ControlOutput

        Raises
        ------
        ControllerInputError
            For a wrong shape, a NaN / Inf or a dt_s that is not > 0; the state of the
            controller (and of its filter) is unchanged.

        Notes
        -----
        Each stage runs the float path of its class (a hundred-odd multiply-adds
        in all), because numpy's per-call overhead on 3-vectors would dominate.
        """
        start = time.perf_counter()
        x, y = self._check(X, preview)
        if dt_s is not None:
            dt_s = self._interval(dt_s)
            self.drive.advance(dt_s)
        px, vx, py, vy, theta, w = x
        if self.estimator is not None:
            px, py, theta = self.estimator.update(px, vx, py, vy, theta, w, dt_s)
            x = [px, vx, py, vy, theta, w]
        theta_m = theta + 0.5 * self.period_s * w
        u_prev = self._u_prev
        self._last = (x, u_prev, y)
        infeasible = False
        if self.constrained is None:
            du_x, du_y, du_theta = self.mpc.delta_u(x, u_prev, y)
            u = [u_prev[0] + du_x, u_prev[1] + du_y, u_prev[2] + du_theta]
        else:
            u, infeasible = self.constrained.solve_floats(x, u_prev, y, self.drive.current_estimate)
        currents = self.drive.currents(self.field.forces(theta_m, u))
        ux, uy, uw = u
        dx, dy, dw = self._damping_rates
        omega, omega_rate = self.kinematics.speeds_and_rates(
            theta, (vx, vy, w), (ux - dx * vx, uy - dy * vy, uw - dw * w))
        rate_of_current = lambda i: self._rate_of_current(theta, theta_m, (vx, vy, w), i)  # noqa: E731
        if self.current_limit_a > 0.0:
            rest = (-dx * vx, -dy * vy, -dw * w)
            voltages, saturated, mean_current, scale = self.drive.limited_step(
                currents,
                omega,
                omega_rate,
                lambda: self.kinematics.speeds_and_rates(theta, (vx, vy, w), rest)[1],
                self.current_limit_a,
                rate_of_current,
            )
            if scale < 1.0:
                u = [scale * ux, scale * uy, scale * uw]
                currents = [scale * i for i in currents]
        else:
            voltages, saturated, mean_current = self.drive.step(currents, omega, omega_rate, rate_of_current)
        self._u_prev = self._acceleration_of_current(theta_m, mean_current) if saturated else u
        return ControlOutput(
            tuple(voltages), tuple(currents), tuple(u), saturated, infeasible, time.perf_counter() - start
        )

    @property
    def u_prev(self) -> np.ndarray:
        """u(k-1), the accelerations applied in the last period (eq. 48)."""
        return np.array(self._u_prev)

    def predicted_outputs(self) -> np.ndarray:
        """The MPCs' prediction at the last step: y(k+1) .. y(k+N) (x, y, theta in odom), shape (N, 3).

        Eq. (50), Y = G_p x(k) + F_1p Delta U + F_2p u(k-1) (F_1p, F_2p with erratum 3), under the optimal
        increments Delta U of eq. (56) for the state (filtered pose), u(k-1) and preview of the last
        `step`. Computed on demand (`DecoupledMPC.predicted`, one product), so a step does not pay for it.

        Raises
        ------
        ControllerInputError
            Before the first step after construction or `reset`.
        """
        return self.mpc.predicted(*self._last_step())

    def next_velocity(self) -> tuple[float, float, float]:
        """The body velocity (v_x, v_y, theta') in base_link the model predicts at t + Ts under the applied u(k).

        Per axis the velocity row of eq. (49), v(k+1) = A_d[1] x(k) + B_d[1] u(k) (u(k) as applied: scaled by
        a current limit or the acceleration of clipped voltages), rotated by the predicted heading theta(k+1):
        v_body = R(theta)^T v_odom (REP-103). The command of a velocity interface (cmd_vel).

        Raises
        ------
        ControllerInputError
            Before the first step after construction or `reset`.
        """
        x = self._last_step()[0]
        u = self._u_prev
        A, B = self.mpc.A_d, self.mpc.B_d
        vx, vy, w = (float(A[a, 1] @ x[2 * a: 2 * a + 2] + B[a, 1] * u[a]) for a in range(3))
        theta = float(A[2, 0] @ x[4:6] + B[2, 0] * u[2])
        c, s = math.cos(theta), math.sin(theta)
        return (c * vx + s * vy, -s * vx + c * vy, w)

    def _last_step(self) -> tuple[list[float], list[float], list[list[float]]]:
        """(x, u(k-1), preview) of the last step, or ControllerInputError before one."""
        if self._last is None:
            raise ControllerInputError("no step since the controller was built or reset: nothing predicted yet")
        return self._last


def states_from_odometry(pose: object, twist_body: object) -> np.ndarray:
    """Body states X = (x, x', y, y', theta, theta') of eq. (2) from odometry measurements of B runs (the batch form).

    Parameters
    ----------
    pose
        Measured (x, y, theta) in the odom frame, shape (..., 3) (a batch axis, or none for one measurement).
    twist_body
        (v_x, v_y, theta') in the robot frame, as nav_msgs/Odometry carries it, the same shape.

    Returns
    -------
    ndarray, shape (..., 6)
        The velocity rotated into the odom frame by the *measured* heading
        (all a controller on the robot knows). `state_from_odometry` is one run's form.
    """
    pose, twist = np.asarray(pose, dtype=float), np.asarray(twist_body, dtype=float)
    if pose.shape[-1:] != (3,) or twist.shape != pose.shape:
        raise ControllerInputError(f"pose and twist_body must both have shape (..., 3), got {pose.shape} and "
                                   f"{twist.shape}")
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    vx, vy = twist[..., 0], twist[..., 1]
    state = np.empty((*pose.shape[:-1], 6))
    state[..., 0::2] = pose
    np.subtract(c * vx, s * vy, out=state[..., 1])
    np.add(s * vx, c * vy, out=state[..., 3])
    state[..., 5] = twist[..., 2]
    return state


def step_interval(stamp_ns: int, last_ns: int | None, period_ns: int) -> float | None:
    """The `dt_s` of `MotionController.step` for a measurement stamped `stamp_ns` after one stamped `last_ns`.

    None (one period) for the first measurement and for an interval of exactly one period; else the
    interval in seconds. The controller node and `regress` use it, so a replay steps as the node did.
    """
    dt_ns = period_ns if last_ns is None else stamp_ns - last_ns
    return None if dt_ns == period_ns else dt_ns * 1e-9


def state_from_odometry(
    pose: tuple[float, float, float], twist_body: tuple[float, float, float]
) -> tuple[float, float, float, float, float, float]:
    """X of eq. (2) from one odometry measurement, on three plus three Python floats, unchecked (the per-tick form;
    `states_from_odometry` for arrays): the velocity rotated into ``odom`` by the measured heading.
    """
    x, y, theta = pose
    vx, vy, w = twist_body
    c, s = math.cos(theta), math.sin(theta)
    return (x, c * vx - s * vy, y, s * vx + c * vy, theta, w)
