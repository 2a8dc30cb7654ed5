"""A wheel-speed PI loop on the DC drives, as the Robotino firmware closes it under a cmd_vel driver (no rclpy).

A velocity-controlled base takes a body twist (v_x, v_y, theta') in base_link,
turns it into the three motor-speed setpoints through the wheel kinematics
(`model.dynamics.motor_speeds`; in base_link the heading is 0) and holds each
motor at its setpoint with a PI controller on the armature voltage:

    e_i = omega*_i - omega_i,   U_i = clip(kp e_i + ki I_i, +-supply),   I_i' = e_i (unless U_i is clipped and
    e_i pushes further into the clip: conditional-integration anti-windup),

sampled at ``rate_hz`` (1 kHz) with the voltage held between samples; each sample period is one exact ZOH
step of `plant.RobotinoPlant.step`.

Tuning (`tuned_gains`, the default gains): per motor the body looks like an inertia
J_eff = (M / 1.5) (r / gear)^2 (three wheels at 120 degrees share a translation: sum d_i d_i^T = 1.5 I; M
holds the reflected rotors) with a damping b = (k_x / 1.5) (r / gear)^2 + b_motor, behind the back-EMF:
omega / U = K / (tau_m s + 1), tau_m = J_eff / (Km^2 / R + b), K = (Km / R) / (Km^2 / R + b) (tau_m = 0.20 s
for the Robotino 3 preset, GR 42x25: R = 5.95 Ohm, Km = 0.0514 N m/A, gear 16, r = 0.04 m). The PI's zero
cancels that pole (ki / kp = 1 / tau_m), leaving a first-order speed loop of time constant
tau_cl = tau_m / (K kp): kp = tau_m / (K tau_cl), ki = kp / tau_m, tau_cl = 25 ms (the
firmware's order of magnitude: 2.5 control periods, yet 17 times the electrical time constant L / R = 1.5 ms
and 25 samples at 1 kHz). Robotino 3 preset: kp = 0.418 V s/rad, ki = 2.26 V/rad (`DEFAULT_KP`, `DEFAULT_KI`).
"""

from __future__ import annotations

import math

import numpy as np

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.model.dynamics import motor_speeds
from robotino_geom_mpc.params.specs import ParamSpec, RobotinoParams

__all__ = ["DEFAULT_KI", "DEFAULT_KP", "DEFAULT_RATE_HZ", "SPEED_LOOP_TIME_CONSTANT_S", "WHEEL_PI_DEFAULTS",
           "WHEEL_PI_SPECS", "WheelSpeedLoop", "WheelSpeedLoopError", "tuned_gains"]

SPEED_LOOP_TIME_CONSTANT_S = 0.025
# `tuned_gains` of the Robotino 3 preset, rounded (the plant node's defaults: simulate and run use the same)
DEFAULT_KP = 0.418
DEFAULT_KI = 2.26
DEFAULT_RATE_HZ = 1000.0

# the plant node's parameters of the loop (``command_interface`` cmd_vel)
WHEEL_PI_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("command_interface", str, "voltages: wheel_voltages drive the motors; cmd_vel: a base_link twist held "
              "by per-wheel PI speed loops (wheel_pi.*)", choices=("voltages", "cmd_vel")),
    ParamSpec("wheel_pi.kp", float, "cmd_vel: proportional gain of each wheel's speed loop (on the motor speed)",
              "V s/rad", 0.0, 100.0, True),
    ParamSpec("wheel_pi.ki", float, "cmd_vel: integral gain of each wheel's speed loop", "V/rad", 0.0, 1e4, True),
    ParamSpec("wheel_pi.rate_hz", float, "cmd_vel: sampling rate of the speed loops (voltage held in between)", "Hz",
              10.0, 1e5, False),
)
WHEEL_PI_DEFAULTS = {"command_interface": "voltages", "wheel_pi.kp": DEFAULT_KP, "wheel_pi.ki": DEFAULT_KI,
                     "wheel_pi.rate_hz": DEFAULT_RATE_HZ}


class WheelSpeedLoopError(RobotinoError, ValueError):
    """Gains or a rate that are not finite and positive, or a twist that is not three finite numbers."""


def tuned_gains(p: RobotinoParams, time_constant_s: float = SPEED_LOOP_TIME_CONSTANT_S) -> tuple[float, float]:
    """(kp [V s/rad], ki [V/rad]) of a first-order speed loop of `time_constant_s` (module docstring)."""
    reflect = (p.r / p.gear_ratio) ** 2 / 1.5
    damping = p.k_x * reflect + p.viscous_friction_n_m_s
    electrical = p.torque_constant_n_m_per_a**2 / p.resistance_ohm
    tau_m = p.M * reflect / (electrical + damping)
    gain = p.torque_constant_n_m_per_a / p.resistance_ohm / (electrical + damping)
    kp = tau_m / (gain * time_constant_s)
    return kp, kp / tau_m


class WheelSpeedLoop:
    """The per-wheel PI speed loops of a velocity-controlled Robotino.

    Parameters
    ----------
    robot
        The robot whose kinematics turn a twist into motor speeds (and whose supply clips the voltages).
    kp
        Proportional gain [V s/rad] on the motor-speed error.
    ki
        Integral gain [V/rad].
    rate_hz
        Sampling rate of the loops [Hz].
    """

    def __init__(self, robot: RobotinoParams, kp: float = DEFAULT_KP, ki: float = DEFAULT_KI,
                 rate_hz: float = DEFAULT_RATE_HZ) -> None:
        for name, value in (("kp", kp), ("ki", ki), ("rate_hz", rate_hz)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise WheelSpeedLoopError(f"{name} must be a finite number > 0, got {value!r}")
        self.robot = robot
        self.kp, self.ki, self.rate_hz = float(kp), float(ki), float(rate_hz)
        self.reset()

    def reset(self) -> None:
        """Integrators to zero (drives off)."""
        self.integral = [0.0, 0.0, 0.0]

    def setpoints(self, twist_body: object) -> np.ndarray:
        """Motor-speed setpoints omega* [rad/s] of a base_link twist (v_x [m/s], v_y [m/s], theta' [rad/s])."""
        twist = checked_array(twist_body, (3,), "twist_body", WheelSpeedLoopError)
        return motor_speeds(0.0, twist, self.robot)

    def voltages(self, setpoints: list[float], speeds: list[float], h: float) -> list[float]:
        """One sample: the PI voltages [V] for the motor `speeds` [rad/s], integrators advanced by `h` [s]."""
        supply = self.robot.supply_voltage_v
        out = []
        for i, (target, speed) in enumerate(zip(setpoints, speeds)):
            error = target - speed
            integral = self.integral[i] + error * h
            u = self.kp * error + self.ki * integral
            if abs(u) > supply:
                u = math.copysign(supply, u)
                if error * u > 0.0:  # pushing further into the clip: hold the integrator
                    integral = self.integral[i]
            self.integral[i] = integral
            out.append(u)
        return out

    def run(self, plant, twist_body: object, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Drive `plant` (a `plant.RobotinoPlant`) for `duration_s` towards the twist, one ZOH step per sample.

        Returns
        -------
        voltages : ndarray, shape (n, 3)
            The voltages held over each of the n = round(duration_s rate_hz) samples [V].
        currents : ndarray, shape (m, 3)
            The plant's currents at the start and at every internal substep end of each sample [A].
        """
        if not (math.isfinite(duration_s) and duration_s > 0.0):
            raise WheelSpeedLoopError(f"duration_s must be finite and > 0, got {duration_s!r}")
        setpoints = self.setpoints(twist_body).tolist()
        n = max(1, round(duration_s * self.rate_hz))
        h = duration_s / n
        gear = self.robot.gear_ratio
        voltages, currents = [], []
        for _ in range(n):
            u = self.voltages(setpoints, [gear * w for w in plant.wheel_speeds.tolist()], h)
            plant.step(u, h)
            voltages.append(u)
            currents.append(plant.substep_currents)
        return np.array(voltages), np.concatenate(currents)
