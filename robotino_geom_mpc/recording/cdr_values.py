"""The few values the report takes from the loop's recorded messages, read straight from their CDR bytes.

A 20 s run's report reads 10 000 odometry, preview and three-value
messages; rosbags' decoder builds every field of each (the preview's five
points, the odometry's covariances) for 0.1-0.3 ms a message, and these
readers skip to the values wanted by the CDR rules (little-endian
encapsulation; strings and sequences a uint32 count first; primitives
aligned to their size, counted from the end of the 4-byte encapsulation
header). Each reader takes the serialized bytes and returns a tuple, and the
matching ``*_of_message`` function takes the same values from a decoded
message (any object with the message's field names): `values_of` uses it for
bytes the reader cannot walk (big-endian, truncated).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from robotino_geom_mpc.ros.decode import stamp_ns, yaw_of

__all__ = [
    "diagnostics_with", "diagnostics_with_of_message", "odometry_pose", "odometry_pose_of_message", "preview_start",
    "preview_start_of_message", "three_values", "three_values_of_message", "values_of",
]

_LITTLE_ENDIAN = (b"\x00\x01", b"\x00\x03")  # CDR_LE, PL_CDR_LE
_STAMP = struct.Struct("<iI")
_UINT32 = struct.Struct("<I")
_POSE = struct.Struct("<7d")  # position x, y, z; orientation x, y, z, w (geometry_msgs/Pose, Transform)


class _Unreadable(ValueError):
    """Bytes the readers do not walk (not little-endian CDR, or truncated)."""


def _align(pos: int, size: int) -> int:
    return pos + (-(pos - 4)) % size


def _count(data: bytes, pos: int) -> tuple[int, int]:
    """(uint32 at `pos` aligned to 4, the position after it)."""
    pos = _align(pos, 4)
    return _UINT32.unpack_from(data, pos)[0], pos + 4


def _skip_string(data: bytes, pos: int) -> int:
    length, pos = _count(data, pos)
    return pos + length


def _header(data: bytes) -> tuple[int, int]:
    """(std_msgs/Header stamp [ns], the position after its frame_id)."""
    if data[:2] not in _LITTLE_ENDIAN:
        raise _Unreadable("not little-endian CDR")
    sec, nanosec = _STAMP.unpack_from(data, 4)
    return sec * 1_000_000_000 + nanosec, _skip_string(data, 12)


def _pose_after(data: bytes, pos: int) -> tuple[float, float, float]:
    x, y, _, qx, qy, qz, qw = _POSE.unpack_from(data, _align(pos, 8))
    return (x, y, yaw_of(qx, qy, qz, qw))


def odometry_pose(data: bytes) -> tuple[int, tuple[float, float, float]]:
    """nav_msgs/Odometry bytes -> (header stamp [ns], (x, y, yaw) of pose.pose)."""
    stamp, pos = _header(data)
    return stamp, _pose_after(data, _skip_string(data, pos))  # child_frame_id, then the pose


def odometry_pose_of_message(msg: Any) -> tuple[int, tuple[float, float, float]]:
    """`odometry_pose` of a decoded message."""
    pose = msg.pose.pose
    q = pose.orientation
    return stamp_ns(msg.header.stamp), (pose.position.x, pose.position.y, yaw_of(q.x, q.y, q.z, q.w))


def preview_start(data: bytes) -> tuple[int, tuple[float, float, float] | None]:
    """trajectory_msgs/MultiDOFJointTrajectory bytes -> (header stamp [ns], (x, y, yaw) of point 0's first
    transform, None if there is none).
    """
    stamp, pos = _header(data)
    names, pos = _count(data, pos)
    for _ in range(names):
        pos = _skip_string(data, pos)
    points, pos = _count(data, pos)
    if points == 0:
        return stamp, None
    transforms, pos = _count(data, pos)
    return stamp, (_pose_after(data, pos) if transforms else None)


def preview_start_of_message(msg: Any) -> tuple[int, tuple[float, float, float] | None]:
    """`preview_start` of a decoded message."""
    if not msg.points or not msg.points[0].transforms:
        return stamp_ns(msg.header.stamp), None
    tf = msg.points[0].transforms[0]
    q = tf.rotation
    return stamp_ns(msg.header.stamp), (tf.translation.x, tf.translation.y, yaw_of(q.x, q.y, q.z, q.w))


def three_values(data: bytes) -> tuple[float, ...]:
    """std_msgs/Float64MultiArray bytes -> its data (the report needs three values; any count is read)."""
    if data[:2] not in _LITTLE_ENDIAN:
        raise _Unreadable("not little-endian CDR")
    dims, pos = _count(data, 4)
    for _ in range(dims):
        pos = _align(_skip_string(data, pos), 4) + 8  # label, then size and stride (uint32)
    count, pos = _count(data, _align(pos, 4) + 4)  # data_offset, then data's count
    return struct.unpack_from(f"<{count}d", data, _align(pos, 8)) if count else ()


def three_values_of_message(msg: Any) -> tuple[float, ...]:
    """`three_values` of a decoded message."""
    return tuple(float(v) for v in msg.data)


def _string(data: bytes, pos: int) -> tuple[str, int]:
    length, pos = _count(data, pos)
    if length == 0 or pos + length > len(data):
        raise _Unreadable("a string past the end of the message")
    return data[pos : pos + length - 1].decode(), pos + length  # without the terminating NUL


def diagnostics_with(key: str) -> Callable[[bytes], tuple[int, dict[str, str] | None]]:
    """A reader of diagnostic_msgs/DiagnosticArray bytes -> (header stamp [ns], the key-values of the first
    status that has `key`, None if none has).
    """

    def read(data: bytes) -> tuple[int, dict[str, str] | None]:
        stamp, pos = _header(data)
        statuses, pos = _count(data, pos)
        for _ in range(statuses):
            pos = _skip_string(data, _skip_string(data, _skip_string(data, pos + 1)))  # level; name, message, id
            count, pos = _count(data, pos)
            values = {}
            for _ in range(count):
                name, pos = _string(data, pos)
                values[name], pos = _string(data, pos)
            if key in values:
                return stamp, values
        return stamp, None

    return read


def diagnostics_with_of_message(key: str) -> Callable[[Any], tuple[int, dict[str, str] | None]]:
    """`diagnostics_with` of a decoded message."""

    def of_message(msg: Any) -> tuple[int, dict[str, str] | None]:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if key in values:
                return stamp_ns(msg.header.stamp), values
        return stamp_ns(msg.header.stamp), None

    return of_message


def values_of(data: bytes, read: Callable[[bytes], Any], of_message: Callable[[Any], Any],
              decode: Callable[[], Any]) -> Any:
    """`read(data)`, else `of_message(decode())` for bytes `read` does not walk (`decode` raises as it will)."""
    try:
        return read(data)
    except (_Unreadable, struct.error, IndexError, UnicodeDecodeError):
        return of_message(decode())

