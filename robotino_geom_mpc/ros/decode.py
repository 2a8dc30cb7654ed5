"""Values of decoded odometry and preview messages, as the controller and `regress` read them (no rclpy needed).

The functions take any object with the messages' field names: rclpy's
message classes, rosbags' or mcap-ros2-support's decoded messages. The
``*_of_message`` functions take from a decoded message what `ros.cdr`'s
readers of the same name take from its bytes (the report's fallback). The
checks of the values read (`check_yaw_quaternion`, `stamp_problem`,
`state_of_odometry`, `preview_of_values`, `InputRejected`) live in
`loop.inputs`, where the controller loop makes them; they are offered here too.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from robotino_geom_mpc.loop.events import Odometry, Preview, Undecodable
from robotino_geom_mpc.loop.inputs import (QUATERNION_NORM_TOLERANCE, TILT_TOLERANCE_RAD, InputRejected,
                                           check_yaw_quaternion, preview_of_values, stamp_problem,
                                           state_of_odometry, time_ns, unwrap_near, yaw_of)

__all__ = [
    "check_yaw_quaternion", "diagnostics_with_of_message", "float64_array_of_message", "InputRejected",
    "ODOM_FIELDS", "odometry_input", "odometry_pose_of_message", "odometry_state", "odometry_values", "POINT_FIELDS",
    "preview_arrays", "preview_input", "preview_of_values", "preview_point_values", "preview_start_of_message",
    "QUATERNION_NORM_TOLERANCE", "STAMP_FIELDS", "stamp_ns", "stamp_problem", "state_of_odometry",
    "TILT_TOLERANCE_RAD", "time_ns", "unwrap_near", "yaw_of",
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


def stamp_ns(stamp) -> int:
    """A decoded builtin_interfaces/Time (rclpy's, rosbags' or mcap's) as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def odometry_values(msg) -> tuple:
    """(stamp sec, stamp nanosec, x, y, q_x, q_y, q_z, q_w, v_x, v_y, omega) of a decoded odometry message."""
    p, q, tw = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, p.x, p.y, q.x, q.y, q.z, q.w,
            tw.linear.x, tw.linear.y, tw.angular.z)


def odometry_input(msg) -> Odometry | Undecodable:
    """The controller loop's `loop.events.Odometry` of a decoded odometry message (a stamp that is no time:
    `loop.events.Undecodable`, as the node hands it on).
    """
    values = odometry_values(msg)
    try:
        return Odometry(time_ns(values[0], values[1]), tuple(values[2:]))
    except InputRejected as exc:
        return Undecodable("odom", None, exc.reason, str(exc))


def preview_input(msg) -> Preview | Undecodable:
    """The controller loop's `loop.events.Preview` of a decoded preview (any number of points: the loop checks); a
    stamp that is no time or a point without its one transform: `loop.events.Undecodable`, as the node hands it on.
    """
    stamp = None
    try:
        stamp = time_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)
        return Preview(stamp, msg.header.frame_id, preview_point_values(msg, None))
    except InputRejected as exc:
        return Undecodable("reference_preview", stamp, exc.reason, str(exc))


def odometry_state(msg, previous_theta: float, norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                   tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> np.ndarray:
    """`state_of_odometry` of a decoded odometry message."""
    return state_of_odometry(odometry_values(msg)[2:], previous_theta, norm_tolerance, tilt_tolerance_rad)


def preview_point_values(msg, horizon: int | None) -> tuple:
    """Per point 0..N of a decoded preview: x, y, q_x, q_y, q_z, q_w, velocity and acceleration (x, y, theta), flat.

    A point without velocities or accelerations gets zeros there (its pose is then used as it is). `horizon`
    None takes any number of points (the controller loop checks the count).

    Raises
    ------
    InputRejected
        If the message does not have N + 1 points with one transform (and at most one velocity and
        acceleration) each.
    """
    if horizon is not None and len(msg.points) != horizon + 1:
        raise InputRejected(f"reference_preview has {len(msg.points)} points, need N + 1 = {horizon + 1}", "size")
    out: list[float] = []
    for j, point in enumerate(msg.points):
        if len(point.transforms) != 1 or len(point.velocities) > 1 or len(point.accelerations) > 1:
            raise InputRejected(f"reference_preview point {j} has {len(point.transforms)} transforms, "
                                f"{len(point.velocities)} velocities, {len(point.accelerations)} accelerations; "
                                "need 1, at most 1, at most 1", "size")
        tr, q = point.transforms[0].translation, point.transforms[0].rotation
        out += (tr.x, tr.y, q.x, q.y, q.z, q.w)
        for twists in (point.velocities, point.accelerations):
            out += (twists[0].linear.x, twists[0].linear.y, twists[0].angular.z) if twists else (0.0, 0.0, 0.0)
    return tuple(out)


def preview_arrays(msg, horizon: int, theta_near: float, norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                   tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`preview_of_values` of a decoded preview (N + 1 points).

    Raises
    ------
    InputRejected
        If the message does not have the points `preview_point_values` needs, holds non-finite values
        or a rotation that is not a yaw.
    """
    return preview_of_values(preview_point_values(msg, horizon), theta_near, norm_tolerance, tilt_tolerance_rad)


def odometry_pose_of_message(msg: Any) -> tuple[int, tuple[float, float, float]]:
    """`ros.cdr.odometry_pose` of a decoded message."""
    pose = msg.pose.pose
    q = pose.orientation
    return stamp_ns(msg.header.stamp), (pose.position.x, pose.position.y, yaw_of(q.x, q.y, q.z, q.w))


def preview_start_of_message(msg: Any) -> tuple[int, tuple[float, float, float] | None]:
    """`ros.cdr.preview_start` of a decoded message."""
    if not msg.points or not msg.points[0].transforms:
        return stamp_ns(msg.header.stamp), None
    tf = msg.points[0].transforms[0]
    q = tf.rotation
    return stamp_ns(msg.header.stamp), (tf.translation.x, tf.translation.y, yaw_of(q.x, q.y, q.z, q.w))


def float64_array_of_message(msg: Any) -> tuple[float, ...]:
    """`ros.cdr.float64_array` of a decoded message."""
    return tuple(float(v) for v in msg.data)


def diagnostics_with_of_message(key: str) -> Callable[[Any], tuple[int, dict[str, str] | None]]:
    """`ros.cdr.diagnostics_with` of a decoded message."""

    def of_message(msg: Any) -> tuple[int, dict[str, str] | None]:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if key in values:
                return stamp_ns(msg.header.stamp), values
        return stamp_ns(msg.header.stamp), None

    return of_message
