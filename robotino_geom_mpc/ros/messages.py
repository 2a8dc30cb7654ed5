"""The messages the nodes exchange, built and read: stamps, yaw quaternions, three-value arrays, odometry, previews.

The preview (trajectory -> controller) is a trajectory_msgs/MultiDOFJointTrajectory
in frame ``odom`` with one joint ``base_link`` and N + 1 points j = 0..N,
``time_from_start`` = j Ts, each with one transform (x_d, y_d, yaw quaternion
of theta_d), one velocity and one acceleration (linear x, y, angular z). The
odometry (plant or robot -> controller) is nav_msgs/Odometry ``odom`` ->
``base_link`` (REP-105). The fixed layouts here are what the nodes publish as
`cdr.CdrTemplate` bytes and read in place with `cdr.CdrLayout`; the decoders
of any other layout are in `decode` (plain Python, also used by `regress`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Duration
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import Quaternion, Transform, Twist
from nav_msgs.msg import Odometry
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

from robotino_geom_mpc.reference.trajectories import preview
from robotino_geom_mpc.ros.cdr import CdrLayout, CdrTemplate, aligned
from robotino_geom_mpc.ros.decode import ODOM_FIELDS, POINT_FIELDS, STAMP_FIELDS, yaw_of

__all__ = [
    "BASE_FRAME", "CURRENT_LABEL", "ODOM_FRAME", "VOLTAGE_LABEL", "ns_to_stamp", "odometry_layout", "odometry_message",
    "path_cdr", "point_values",
    "preview_layout", "PreviewLayouts", "preview_message", "preview_skeleton", "preview_template", "preview_values",
    "quaternion_to_yaw", "stamp_to_ns", "three_values", "three_values_layout", "three_values_template",
    "yaw_quaternion_zw", "yaw_to_quaternion",
]

ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
VOLTAGE_LABEL = "wheel_voltage_v"  # layout label of wheel_voltages
CURRENT_LABEL = "wheel_current_a"  # and of wheel_currents

_THREE = ("data[0]", "data[1]", "data[2]")
# the fields of point j the trajectory node sets, in the order of `preview_values`
_WRITTEN_POINT_FIELDS = (
    "transforms[0].translation.x", "transforms[0].translation.y", "transforms[0].rotation.z",
    "transforms[0].rotation.w", "velocities[0].linear.x", "velocities[0].linear.y", "velocities[0].angular.z",
    "accelerations[0].linear.x", "accelerations[0].linear.y", "accelerations[0].angular.z",
)


def stamp_to_ns(stamp: TimeMsg) -> int:
    """builtin_interfaces/Time as integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def ns_to_stamp(ns: int) -> TimeMsg:
    """Integer nanoseconds as builtin_interfaces/Time."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return TimeMsg(sec=sec, nanosec=nanosec)


def yaw_quaternion_zw(theta: float) -> tuple[float, float]:
    """(z, w) of the rotation about z by `theta` (rad), whose x and y are 0 (the templates' yaw fields)."""
    half = 0.5 * theta
    return math.sin(half), math.cos(half)


def yaw_to_quaternion(theta: float) -> Quaternion:
    """Rotation about z by `theta` (rad)."""
    z, w = yaw_quaternion_zw(theta)
    return Quaternion(x=0.0, y=0.0, z=z, w=w)


def quaternion_to_yaw(q: Quaternion) -> float:
    """Yaw (rad, in (-pi, pi]) of a quaternion (ZYX convention)."""
    return yaw_of(q.x, q.y, q.z, q.w)


def three_values(label: str) -> Float64MultiArray:
    """Float64MultiArray of 3 zeros, one layout dimension `label` (forward_command_controller convention)."""
    layout = MultiArrayLayout(dim=[MultiArrayDimension(label=label, size=3, stride=3)])
    return Float64MultiArray(data=[0.0] * 3, layout=layout)


def three_values_template(label: str) -> CdrTemplate:
    """`CdrTemplate` of `three_values`: `pack(a, b, c)`."""
    return CdrTemplate(three_values(label), _THREE)


def three_values_layout(label: str) -> CdrLayout:
    """`CdrLayout` of `three_values`: `read(data)` -> (a, b, c) or None."""
    return CdrLayout(three_values(label), _THREE)


def odometry_message(frame_prefix: str = "") -> Odometry:
    """An Odometry ``<frame_prefix>odom`` -> ``<frame_prefix>base_link`` (REP-105), all values zero."""
    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = frame_prefix + ODOM_FRAME, frame_prefix + BASE_FRAME
    return msg


def odometry_layout(frame_prefix: str = "") -> CdrLayout:
    """The odometry the plant sends (REP-105 frames), read in place: the values of `decode.ODOM_FIELDS`."""
    return CdrLayout(odometry_message(frame_prefix), ODOM_FIELDS)


def point_values(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Rows of point values in the order the trajectory writes them (x, y, yaw quaternion z and w, velocity, acc.)."""
    half = 0.5 * pos[:, 2]
    return np.column_stack((pos[:, :2], np.sin(half), np.cos(half), vel, acc))


def preview_values(reference, t_ns: int, period_s: float, horizon: int) -> list[float]:
    """The values of the N + 1 preview points of tick time `t_ns`, flat, point after point.

    Point 0 is the reference at t itself, points 1..N `reference.trajectories.preview` (eq. 54). Each point's
    velocity and acceleration are sampled one time at a time (the scalar kernel: ~3x faster than one vectorised
    call for a handful of points, the values the same to an ulp; the realtime trajectory node's cost a tick).
    """
    t = t_ns * 1e-9
    samples = [reference.sample(t + period_s * j) for j in range(horizon + 1)]
    pos = np.array([sample[0] for sample in samples])
    pos[1:] = preview(reference, t, period_s, horizon)
    vel = np.array([sample[1] for sample in samples])
    acc = np.array([sample[2] for sample in samples])
    return point_values(pos, vel, acc).ravel().tolist()


def preview_skeleton(period_s: float, horizon: int, frame_prefix: str = "") -> MultiDOFJointTrajectory:
    """The constant part of a preview: frame, joint, N + 1 points with one transform each and their times."""
    msg = MultiDOFJointTrajectory()
    msg.header.frame_id = frame_prefix + ODOM_FRAME
    msg.joint_names = [frame_prefix + BASE_FRAME]
    period_ns = int(round(period_s * 1e9))
    for j in range(horizon + 1):
        sec, nanosec = divmod(j * period_ns, 1_000_000_000)
        msg.points.append(
            MultiDOFJointTrajectoryPoint(
                transforms=[Transform()], velocities=[Twist()], accelerations=[Twist()],
                time_from_start=Duration(sec=sec, nanosec=nanosec),
            )
        )
    return msg


def preview_message(reference, t_ns: int, period_s: float, horizon: int) -> MultiDOFJointTrajectory:
    """The preview of tick time `t_ns` as a MultiDOFJointTrajectory (N + 1 points, see the module docstring)."""
    msg = preview_skeleton(period_s, horizon)
    msg.header.stamp = ns_to_stamp(t_ns)
    values = iter(preview_values(reference, t_ns, period_s, horizon))
    for point in msg.points:
        tf, v, a = point.transforms[0], point.velocities[0], point.accelerations[0]
        tf.translation.x, tf.translation.y, tf.rotation.z, tf.rotation.w = (next(values) for _ in range(4))
        v.linear.x, v.linear.y, v.angular.z = (next(values) for _ in range(3))
        a.linear.x, a.linear.y, a.angular.z = (next(values) for _ in range(3))
    return msg


def preview_template(period_s: float, horizon: int, frame_prefix: str = "") -> CdrTemplate:
    """`CdrTemplate` of the preview: `pack(sec, nanosec, *preview_values(...))` are the bytes of `preview_message`."""
    paths = ("header.stamp.sec", "header.stamp.nanosec") + tuple(
        f"points[{j}].{field}" for j in range(horizon + 1) for field in _WRITTEN_POINT_FIELDS
    )
    return CdrTemplate(preview_skeleton(period_s, horizon, frame_prefix), paths)


def preview_layout(period_s: float, horizon: int, frame_prefix: str = "") -> CdrLayout:
    """The preview the trajectory node sends, read in place: stamp, then `decode.POINT_FIELDS` of each point."""
    return CdrLayout(preview_skeleton(period_s, horizon, frame_prefix), STAMP_FIELDS + tuple(
        f"points[{j}].{f}" for j in range(horizon + 1) for f in POINT_FIELDS))


class PreviewLayouts:
    """`preview_layout` for each preview length seen: N + 1 points from the start, a longer preview's (a trajectory
    node publishing every few periods, with the points to cover them) once the general decoder has read one.

    A length is tried once: one whose layout does not read the preview (another frame prefix) is remembered as
    such, so its next messages go to the general decoder without a layout built again. At most `MAX_LENGTHS`
    lengths are kept (a stray publisher cannot grow it).
    """

    MAX_LENGTHS = 8

    def __init__(self, period_s: float, horizon: int, frame_prefix: str = "") -> None:
        self.period_s, self.frame_prefix = period_s, frame_prefix
        first = preview_layout(period_s, horizon, frame_prefix)
        self.by_size: dict[int, CdrLayout | None] = {first.size: first}

    def read(self, data: bytes) -> tuple | None:
        """`CdrLayout.read` with the layout of `data`'s length; None if there is none, or it does not fit."""
        layout = self.by_size.get(len(data))
        return None if layout is None else layout.read(data)

    def learn(self, data: bytes, points: int) -> None:
        """Keep the layout of a preview of `points` points that the general decoder read from `data`."""
        if len(data) in self.by_size or len(self.by_size) >= self.MAX_LENGTHS or points < 1:
            return
        layout = preview_layout(self.period_s, points - 1, self.frame_prefix)
        self.by_size[len(data)] = layout if layout.read(data) is not None else None


_STAMP_LENGTH = struct.Struct("<iII")  # a header's stamp (sec, nanosec) and its frame_id's length
_UINT32 = struct.Struct("<I")
_PLANAR_POSE = struct.Struct("<7d")  # position (x, y, 0), orientation (0, 0, z, w)


def path_cdr(frame_id: str, stamp_ns: int, pose_stamps_ns: Sequence[int], poses: np.ndarray) -> bytes:
    """The serialized nav_msgs/Path of planar poses, written straight to CDR (`cdr.aligned`'s rules).

    rclpy builds and converts a Path of a run's 2,200 poses in about 0.2 s, during which a trajectory node
    publishes no preview; this takes milliseconds.

    Parameters
    ----------
    frame_id
        The path's and every pose's frame.
    stamp_ns
        The path's stamp [ns].
    pose_stamps_ns
        Each pose's stamp [ns], length n.
    poses
        (x, y, theta) per pose [m, m, rad], shape (n, 3).
    """
    frame = frame_id.encode() + b"\0"
    out = bytearray(b"\x00\x01\x00\x00")  # CDR little-endian

    def pad(size: int) -> None:
        out.extend(bytes(aligned(len(out), size) - len(out)))

    def header(ns: int) -> None:
        pad(4)
        sec, nanosec = divmod(int(ns), 1_000_000_000)
        out.extend(_STAMP_LENGTH.pack(sec, nanosec, len(frame)))
        out.extend(frame)

    header(stamp_ns)
    pad(4)
    out.extend(_UINT32.pack(len(pose_stamps_ns)))
    for ns, (x, y, theta) in zip(pose_stamps_ns, np.asarray(poses, dtype=float).tolist()):
        header(ns)
        pad(8)
        z, w = yaw_quaternion_zw(theta)
        out.extend(_PLANAR_POSE.pack(x, y, 0.0, 0.0, 0.0, z, w))
    return bytes(out)
