"""Values of decoded odometry and preview messages, as the controller and `regress` read them (no rclpy needed).

The functions take any object with the messages' field names: rclpy's
message classes, rosbags' or mcap-ros2-support's decoded messages. The
``*_of_message`` functions take from a decoded message what `ros.cdr`'s
readers of the same name take from its bytes (the report's fallback). The
checks the controller node makes on each input are here too, as plain
float operations on the values already read (`check_yaw_quaternion`,
`stamp_problem`); a refused input raises `InputRejected`, whose `reason`
is a short key the node counts and reports.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from robotino_geom_mpc.control.motion_controller import odometry_state_floats
from robotino_geom_mpc.errors import RobotinoError

__all__ = [
    "InputRejected", "ODOM_FIELDS", "POINT_FIELDS", "QUATERNION_NORM_TOLERANCE", "STAMP_FIELDS", "TILT_TOLERANCE_RAD",
    "check_yaw_quaternion", "diagnostics_with_of_message", "float64_array_of_message", "odometry_pose_of_message",
    "odometry_state", "odometry_values", "preview_arrays", "preview_of_values", "preview_point_values",
    "preview_start_of_message", "stamp_ns", "stamp_problem", "state_of_odometry", "time_ns", "unwrap_near", "yaw_of",
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
# defaults of the controller's quaternion checks (its parameters quaternion_norm_tolerance, tilt_tolerance_rad)
QUATERNION_NORM_TOLERANCE = 1e-3  # relative: | |q| - 1 | above this is refused
TILT_TOLERANCE_RAD = 0.05  # roll/pitch: the body z axis tilted more than this from the odom z axis is refused


class InputRejected(RobotinoError, ValueError):
    """An odometry or preview message that is refused: non-finite values, wrong size, a quaternion that is not a yaw.

    Attributes
    ----------
    reason
        Short key of the refusal (``non_finite``, ``size``, ``quaternion_norm``, ``quaternion_tilt``, ...).
    """

    def __init__(self, message: str, reason: str = "invalid") -> None:
        super().__init__(message)
        self.reason = reason


def check_yaw_quaternion(qx: float, qy: float, qz: float, qw: float, what: str,
                         norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                         tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> None:
    """Refuse a quaternion that is not a unit rotation about z (the planar robot's heading, REP-103).

    The norm must be within `norm_tolerance` of 1 (relative): the all-zero
    quaternion is no rotation, and (0, 0, 0.5, 0.5) is not pi/4 about z but no
    rotation at all. The rotation may tilt the body's z axis by at most
    `tilt_tolerance_rad` (roll/pitch): the tilt t has cos t = 1 - 2 (q_x^2 + q_y^2) / |q|^2,
    so the test is (q_x^2 + q_y^2) / |q|^2 <= sin^2(t_max / 2).

    Raises
    ------
    InputRejected
        With reason ``quaternion_norm`` or ``quaternion_tilt``; `what` names the input in the message.
    """
    xy = qx * qx + qy * qy
    norm2 = xy + qz * qz + qw * qw
    if not abs(math.sqrt(norm2) - 1.0) <= norm_tolerance:
        raise InputRejected(f"{what} quaternion ({qx:g}, {qy:g}, {qz:g}, {qw:g}) has norm {math.sqrt(norm2):.6g}, "
                            f"not 1 within {norm_tolerance:g}", "quaternion_norm")
    half = math.sin(0.5 * tilt_tolerance_rad)
    if xy > half * half * norm2:
        tilt = math.acos(max(-1.0, 1.0 - 2.0 * xy / norm2))
        raise InputRejected(f"{what} quaternion ({qx:g}, {qy:g}, {qz:g}, {qw:g}) tilts the robot by {tilt:.4g} rad "
                            f"(roll/pitch), more than {tilt_tolerance_rad:g}", "quaternion_tilt")


def stamp_problem(stamp_ns: int, last_ns: int | None, now_ns: int | None, timeout_ns: int,
                  future_ns: int) -> str | None:
    """What is wrong with an input's stamp, as a reason key, or None.

    Parameters
    ----------
    stamp_ns
        The input's header stamp.
    last_ns
        The stamp of the last input of this kind that was used (None: none yet).
    now_ns
        The receiver's clock (None: not comparable, e.g. lockstep, where stamps are simulated time).
    timeout_ns, future_ns
        How old, and how far ahead of `now_ns`, a stamp may be.

    Returns
    -------
    ``"future"`` (ahead of now by more than `future_ns`) or ``"stale"`` (older than `timeout_ns`):
    the input is refused; ``"duplicate"`` (the stamp of the last used one) or ``"old"`` (older than it,
    e.g. a message that arrived late, or a clock that went back): the input is dropped; None: fine.
    """
    if now_ns is not None:
        if stamp_ns - now_ns > future_ns:
            return "future"
        if now_ns - stamp_ns > timeout_ns:
            return "stale"
    if last_ns is not None and stamp_ns <= last_ns:
        return "duplicate" if stamp_ns == last_ns else "old"
    return None


def stamp_ns(stamp) -> int:
    """A decoded builtin_interfaces/Time (rclpy's, rosbags' or mcap's) as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def time_ns(sec: int, nanosec: int) -> int:
    """An input's header stamp (sec, nanosec) as integer nanoseconds.

    Raises
    ------
    InputRejected
        With reason ``stamp`` for a time ROS does not have: sec < 0 or nanosec outside [0, 1e9)
        (``sec = 2^31 - 1, nanosec = 2^32 - 1`` would otherwise overflow the stamps of the answers).
    """
    if sec < 0 or not 0 <= nanosec < 1_000_000_000:
        raise InputRejected(f"stamp ({sec} s, {nanosec} ns) is no time: sec >= 0 and 0 <= nanosec < 1e9", "stamp")
    return sec * 1_000_000_000 + nanosec


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


def state_of_odometry(values: tuple, previous_theta: float, norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                      tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> np.ndarray:
    """Body state X = (x, x', y, y', theta, theta') (eq. 2) of `odometry_values` (without the stamp).

    theta is unwrapped next to `previous_theta`; the base_link twist is
    rotated into ``odom`` by the measured heading (`control.motion_controller.odometry_state_floats`).

    Raises
    ------
    InputRejected
        If any value is not finite (reason ``non_finite``), or the orientation is not a yaw
        (`check_yaw_quaternion` with the tolerances).
    """
    x, y, qx, qy, qz, qw, vx, vy, omega = values
    if not math.isfinite(sum(values)):
        raise InputRejected("odom contains non-finite values", "non_finite")
    check_yaw_quaternion(qx, qy, qz, qw, "odom", norm_tolerance, tilt_tolerance_rad)
    theta = unwrap_near(yaw_of(qx, qy, qz, qw), previous_theta)
    return np.array(odometry_state_floats((x, y, theta), (vx, vy, omega)))


def odometry_state(msg, previous_theta: float, norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                   tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> np.ndarray:
    """`state_of_odometry` of a decoded odometry message."""
    return state_of_odometry(odometry_values(msg)[2:], previous_theta, norm_tolerance, tilt_tolerance_rad)


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
        raise InputRejected(f"reference_preview has {len(msg.points)} points, need N + 1 = {horizon + 1}", "size")
    out = []
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


def preview_of_values(values: tuple, theta_near: float, norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                      tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (x, y, theta), velocities and accelerations of `preview_point_values`, each (N + 1, 3).

    Theta is unwrapped from `theta_near`.

    Raises
    ------
    InputRejected
        If a value is not finite (reason ``non_finite``) or a point's rotation is not a yaw
        (`check_yaw_quaternion` with the tolerances, on every point).
    """
    if not math.isfinite(sum(values)):
        raise InputRejected("reference_preview contains non-finite values", "non_finite")
    points = np.array(values, dtype=float).reshape(-1, _POINT_SIZE)
    quaternions = points[:, 2:6]
    squares = quaternions * quaternions
    norm2 = squares.sum(axis=1)
    half = math.sin(0.5 * tilt_tolerance_rad)
    bad = (np.abs(np.sqrt(norm2) - 1.0) > norm_tolerance) | (squares[:, 0] + squares[:, 1] > half * half * norm2)
    if bad.any():  # the vectorised test found one: name it with the scalar check
        j = int(np.argmax(bad))
        check_yaw_quaternion(*quaternions[j].tolist(), f"reference_preview point {j}", norm_tolerance,
                             tilt_tolerance_rad)
    positions = np.empty((len(points), 3))
    theta = theta_near
    for j, (x, y, qx, qy, qz, qw) in enumerate(points[:, :6].tolist()):
        theta = unwrap_near(yaw_of(qx, qy, qz, qw), theta)
        positions[j] = (x, y, theta)
    return positions, points[:, 6:9], points[:, 9:12]


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
