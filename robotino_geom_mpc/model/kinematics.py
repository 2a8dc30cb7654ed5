"""Motor speeds omega = W(theta) v of the three drives and their rate, for the controller (eqs. 9-10).

The rim speed of wheel i is d_i(theta) . (x', y') + l theta' (`model.dynamics.wheel_rim_speeds`) and its motor
turns gear / r times as fast; d_i(theta) = R(theta) d_i(0) turns W(theta) into W(0) on body-frame vectors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from robotino_geom_mpc.model.dynamics import wheel_directions
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = ["MotorKinematics", "MotorKinematicsBatch"]


class MotorKinematics:
    """Motor speeds omega = W(theta) v and their rate, the per-tick form of `model.motor_speeds`.

    W(theta) = (gear / r) [d_i(theta), l] with d_i(theta) = R(theta) d_i(0)
    (R the planar rotation), so W(theta) = W(0) diag(R(theta)^T, 1): the
    odom-frame velocity turned into the body frame, one small product per
    tick instead of rebuilding the wheel directions.

    Parameters
    ----------
    p
        Wheel radius, wheel distance l and gear ratio.
    """

    def __init__(self, p: RobotinoParams) -> None:
        self.W0 = p.gear_ratio / p.r * np.column_stack((wheel_directions(0.0), np.full(3, p.l)))
        self._W0 = tuple(map(tuple, self.W0.tolist()))

    def matrix(self, theta: float) -> np.ndarray:
        """W(theta), shape (3, 3): omega = W(theta) (x', y', theta')."""
        c, s = math.cos(theta), math.sin(theta)
        return self.W0 @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])

    def speeds_and_rates(
        self, theta: float, velocity: Sequence[float], acceleration: Sequence[float]
    ) -> tuple[list[float], list[float]]:
        """Motor speeds omega and their rate omega' for a body velocity and acceleration, one run on Python floats.

        Parameters
        ----------
        theta
            Heading [rad].
        velocity, acceleration
            (x', y', theta') and (x'', y'', theta'') in the odom frame.

        Returns
        -------
        omega, omega_rate : lists of 3 floats
            omega = W(0) R(theta)^T v and omega' = W(theta) a + theta' W'(theta) v, where
            W'(theta) v = W(theta) (y', -x', 0): both are W(0) applied to body-frame vectors. The per-tick path:
            numpy on one run would cost 26 times as much (``bench float_path``); B runs: `MotorKinematicsBatch`.
        """
        vx, vy, w = velocity[0], velocity[1], velocity[2]
        ax, ay, aw = acceleration[0], acceleration[1], acceleration[2]
        c, s = math.cos(theta), math.sin(theta)
        bx, by = ax + w * vy, ay - w * vx
        px, py = c * vx + s * vy, c * vy - s * vx
        qx, qy = c * bx + s * by, c * by - s * bx
        (a0, b0, e0), (a1, b1, e1), (a2, b2, e2) = self._W0
        return (
            [a0 * px + b0 * py + e0 * w, a1 * px + b1 * py + e1 * w, a2 * px + b2 * py + e2 * w],
            [a0 * qx + b0 * qy + e0 * aw, a1 * qx + b1 * qy + e1 * aw, a2 * qx + b2 * qy + e2 * aw],
        )


class MotorKinematicsBatch:
    """The kinematics of B robots at once: W(0) of shape (B, 3, 3), or (3, 3) when the runs share their wheels
    (one product for all of them).

    Parameters
    ----------
    robots
        Each run's wheel radius, wheel distance and gear ratio (B >= 1).
    """

    def __init__(self, robots: Sequence[RobotinoParams]) -> None:
        made: dict[tuple[float, float, float], np.ndarray] = {}  # runs with the same wheels share W(0)
        for p in robots:
            if (p.gear_ratio, p.r, p.l) not in made:
                made[p.gear_ratio, p.r, p.l] = MotorKinematics(p).W0
        self.W0 = made.popitem()[1] if len(made) == 1 else np.stack([made[p.gear_ratio, p.r, p.l] for p in robots])

    def speeds_and_rates(
        self, theta: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """`MotorKinematics.speeds_and_rates` of each run: theta (B,), velocity and acceleration (B, 3) -> omega and
        omega' (B, 3).
        """
        theta = np.asarray(theta, dtype=float)
        v, a = np.asarray(velocity, dtype=float), np.asarray(acceleration, dtype=float)
        c, s = np.cos(theta), np.sin(theta)
        vx, vy, w = v[..., 0], v[..., 1], v[..., 2]
        bx, by = a[..., 0] + w * vy, a[..., 1] - w * vx
        velocity_body, rate_body = np.empty((2, *c.shape, 3))  # R(theta)^T of the velocity and of the rate
        np.add(c * vx, s * vy, out=velocity_body[..., 0])
        np.subtract(c * vy, s * vx, out=velocity_body[..., 1])
        velocity_body[..., 2] = w
        np.add(c * bx, s * by, out=rate_body[..., 0])
        np.subtract(c * by, s * bx, out=rate_body[..., 1])
        rate_body[..., 2] = a[..., 2]
        if self.W0.ndim == 2:  # one W(0) for every run
            return velocity_body @ self.W0.T, rate_body @ self.W0.T
        return (np.einsum("...ij,...j->...i", self.W0, velocity_body),
                np.einsum("...ij,...j->...i", self.W0, rate_body))
