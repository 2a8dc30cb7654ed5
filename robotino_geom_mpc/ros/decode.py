"""Values of decoded odometry and preview messages, as the controller and `regress` read them (no rclpy needed).

The functions take any object with the messages' field names: rclpy's
message classes, rosbags' or mcap-ros2-support's decoded messages.
"""

from __future__ import annotations

import math

import numpy as np

from robotino_geom_mpc.core.controller import odometry_state_floats
from robotino_geom_mpc.core.errors import RobotinoError

__all__ = [
    "InputRejected", "ODOM_FIELDS", "POINT_FIELDS", "STAMP_FIELDS", "odometry_state", "odometry_values",
    "preview_arrays", "preview_of_values", "preview_point_values", "state_of_odometry", "unwrap_near", "yaw_of",
]

STAMP_FIELDS = ("header.stamp.sec", "header.stamp.nanosec")
# the odometry fields the controller reads, in the order of `odometry_values`
ODOM_FIELDS = STAMP_FIELDS + tuple("pose.pose." + f for f in (
    "position.x", "position.y", "orientation.x", "orientation.y", "orientation.z", "orientation.w")) + (
    "twist.twist.linear.x", "twist.twist.linear.y", "twist.twist.angular.z")
# per preview point: pose (x, y, yaw quaternion), then velocity and acceleration (x, y, theta)
POINT_FIELDS = tuple(f"transforms[0].{f}" for f in (
    "translation.x", "translation.y", "rotation.x", "rotation.y", "rotation.z", "rotation.w")) + tuple(
    f"{kind}[0].{f}" for kind in ("velocities", "accelerations") for f in ("linear.x", "linear.y", "angular.z"))
_POINT_SIZE = len(POINT_FIELDS)


class InputRejected(RobotinoError, ValueError):
    """An odometry or preview message with non-finite values or the wrong size."""


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rad, in (-pi, pi]) of the quaternion (x, y, z, w) (ZYX convention)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def unwrap_near(angle: float, reference: float) -> float:
    """`angle + 2 pi k` closest to `reference` (continuous yaw from a wrapped one)."""
    return angle + 2.0 * math.pi * round((reference - angle) / (2.0 * math.pi))


def odometry_values(msg) -> tuple:
    """(stamp sec, stamp nanosec, x, y, q_x, q_y, q_z, q_w, v_x, v_y, omega) of a decoded odometry message."""
    p, q, tw = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, p.x, p.y, q.x, q.y, q.z, q.w,
            tw.linear.x, tw.linear.y, tw.angular.z)


def state_of_odometry(values: tuple, previous_theta: float) -> np.ndarray:
    """Body state X = (x, x', y, y', theta, theta') (eq. 2) of `odometry_values` (without the stamp).

    theta is unwrapped next to `previous_theta`; the base_link twist is
    rotated into ``odom`` by the measured heading (`core.controller.odometry_state_floats`).

    Raises
    ------
    InputRejected
        If any value is not finite.
    """
    x, y, qx, qy, qz, qw, vx, vy, omega = values
    if not math.isfinite(sum(values)):
        raise InputRejected("odom contains non-finite values")
    theta = unwrap_near(yaw_of(qx, qy, qz, qw), previous_theta)
    return np.array(odometry_state_floats((x, y, theta), (vx, vy, omega)))


def odometry_state(msg, previous_theta: float) -> np.ndarray:
    """`state_of_odometry` of a decoded odometry message."""
    return state_of_odometry(odometry_values(msg)[2:], previous_theta)


def preview_point_values(msg, horizon: int) -> tuple:
    """Per point 0..N of a decoded preview: x, y, q_x, q_y, q_z, q_w, velocity and acceleration (x, y, theta), flat.

    A point without velocities or accelerations gets zeros there (its pose is then used as it is).

    Raises
    ------
    InputRejected
        If the message does not have N + 1 points with one transform (and at most one velocity and
        acceleration) each.
    """
    if len(msg.points) != horizon + 1:
        raise InputRejected(f"reference_preview has {len(msg.points)} points, need N + 1 = {horizon + 1}")
    out = []
    for j, point in enumerate(msg.points):
        if len(point.transforms) != 1 or len(point.velocities) > 1 or len(point.accelerations) > 1:
            raise InputRejected(f"reference_preview point {j} has {len(point.transforms)} transforms, "
                                f"{len(point.velocities)} velocities, {len(point.accelerations)} accelerations; "
                                "need 1, at most 1, at most 1")
        tr, q = point.transforms[0].translation, point.transforms[0].rotation
        out += (tr.x, tr.y, q.x, q.y, q.z, q.w)
        for twists in (point.velocities, point.accelerations):
            out += (twists[0].linear.x, twists[0].linear.y, twists[0].angular.z) if twists else (0.0, 0.0, 0.0)
    return tuple(out)


def preview_of_values(values: tuple, theta_near: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (x, y, theta), velocities and accelerations of `preview_point_values`, each (N + 1, 3).

    Theta is unwrapped from `theta_near`.

    Raises
    ------
    InputRejected
        If a value is not finite.
    """
    if not math.isfinite(sum(values)):
        raise InputRejected("reference_preview contains non-finite values")
    points = np.array(values, dtype=float).reshape(-1, _POINT_SIZE)
    positions = np.empty((len(points), 3))
    theta = theta_near
    for j, (x, y, qx, qy, qz, qw) in enumerate(points[:, :6].tolist()):
        theta = unwrap_near(yaw_of(qx, qy, qz, qw), theta)
        positions[j] = (x, y, theta)
    return positions, points[:, 6:9], points[:, 9:12]


def preview_arrays(msg, horizon: int, theta_near: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`preview_of_values` of a decoded preview (N + 1 points).

    Raises
    ------
    InputRejected
        If the message does not have the points `preview_point_values` needs, or holds non-finite values.
    """
    return preview_of_values(preview_point_values(msg, horizon), theta_near)
