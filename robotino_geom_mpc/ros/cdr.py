"""CDR bytes without rclpy's Python conversion: the package's one reader and writer of the CDR rules.

The loop's messages travel as bytes (rclpy's conversions cost more than the control step): `CdrTemplate`
patches a fixed-layout serialization per sample, `CdrLayout` reads numbers from bytes laid out like one
(None otherwise: the general decoder `cdr_reader`, rclpy's, takes those). The report's readers
(`odometry_pose`, `preview_start`, `float64_array`, `diagnostics_with`) walk recorded bytes to the values it
needs; `values_of` falls back to a decoded message. Rules (plain CDR, XCDR1): a 4-byte encapsulation
header (``00 01``: little-endian); a primitive aligned to its size counted from that header's end
(`aligned`); a string a 4-aligned uint32 length, its bytes and a NUL; a sequence a 4-aligned uint32 count
and its elements. rclpy is imported only where needed (templates, `cdr_reader`): the report runs without it.
"""

from __future__ import annotations

import math
import random
import re
import struct
from collections.abc import Callable, Iterable
from operator import itemgetter
from typing import Any

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.ros.decode import yaw_of

__all__ = [
    "CdrLayout", "CdrTemplate", "CdrTemplateError", "ENCAPSULATION_SIZE", "MalformedMessage", "aligned", "cdr_reader",
    "diagnostics_with", "float64_array", "odometry_pose", "preview_start", "values_of",
]

ENCAPSULATION_SIZE = 4
_LITTLE_ENDIAN = (b"\x00\x01", b"\x00\x03")  # CDR_LE, PL_CDR_LE
_STAMP = struct.Struct("<iI")
_UINT32 = struct.Struct("<I")
_POSE = struct.Struct("<7d")  # position x, y, z; orientation x, y, z, w (geometry_msgs/Pose, Transform)


def aligned(position: int, size: int) -> int:
    """`position` moved up to the next multiple of `size` counted from the end of the encapsulation header."""
    return position + (ENCAPSULATION_SIZE - position) % size


class MalformedMessage(RobotinoError, ValueError):
    """Serialized bytes that do not decode as the expected message type."""


def cdr_reader(msg_type: type, type_name: str) -> Callable[[bytes], Any]:
    """A decoder of serialized `msg_type` messages (e.g. ``"nav_msgs/msg/Odometry"`` for `type_name`).

    rclpy's `deserialize_message`, for layouts `CdrLayout` does not read: rare, and free to import (rosbags'
    readers cost a node 0.3-0.5 s at start). Undecodable bytes raise `MalformedMessage`.
    """
    from rclpy.serialization import deserialize_message

    def decode(data: bytes) -> Any:
        try:
            return deserialize_message(data, msg_type)
        except Exception as exc:  # rclpy raises various errors for garbage
            raise MalformedMessage(f"{type_name}: {exc}") from None

    return decode


class CdrTemplateError(RobotinoError, ValueError):
    """A `CdrTemplate` field path that does not name one fixed-size primitive with an unambiguous offset."""


# struct codes of the fixed-size primitive ROS 2 types
_PRIMITIVES = {
    "double": "d", "float": "f", "boolean": "?", "uint8": "B", "int8": "b",
    "int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q",
}
_COMPONENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")
_CONTAINER = re.compile(r"(?:sequence<(?P<seq>[^,>]+)(?:,\s*\d+)?>|(?P<arr>[^\[]+)\[\d+\])$")


def _resolve(msg: Any, path: str) -> tuple[Any, str, int | None, str]:
    """(object holding the field, field name, element index or None, struct code) of a field path."""
    obj, parts = msg, path.split(".")
    for depth, part in enumerate(parts):
        match = _COMPONENT.match(part)
        fields = obj.get_fields_and_field_types() if hasattr(obj, "get_fields_and_field_types") else {}
        if match is None or match.group(1) not in fields:
            raise CdrTemplateError(f"field path {path!r}: no field {part!r} in {type(obj).__name__}")
        name, index = match.group(1), match.group(2)
        kind = fields[name]
        container = _CONTAINER.match(kind)
        if index is not None:
            if container is None:
                raise CdrTemplateError(f"field path {path!r}: {name!r} ({kind}) is not a sequence or array")
            kind = container.group("seq") or container.group("arr")
            index = int(index)
            if index >= len(getattr(obj, name)):
                raise CdrTemplateError(f"field path {path!r}: index {index} beyond the template's "
                                       f"{len(getattr(obj, name))} elements")
        elif container is not None:
            raise CdrTemplateError(f"field path {path!r}: {name!r} ({kind}) is a sequence or array; "
                                   f"patch its elements, e.g. {name}[0]")
        if depth == len(parts) - 1:
            if kind not in _PRIMITIVES:
                raise CdrTemplateError(f"field path {path!r}: {kind} is not a fixed-size primitive "
                                       "(strings and sequences change the layout)")
            return obj, name, index, _PRIMITIVES[kind]
        obj = getattr(obj, name) if index is None else getattr(obj, name)[index]
    raise CdrTemplateError(f"field path {path!r} is empty")  # unreachable for a non-empty split


def _assign(holder: Any, name: str, index: int | None, value: Any) -> None:
    if index is None:
        setattr(holder, name, value)
    else:
        getattr(holder, name)[index] = value


_ROUNDS = 3  # serializations with random field values (16 when a field is one byte: few values to tell apart)


def _sentinel(code: str, rng: random.Random) -> Any:
    """A random value of type `code` (finite for floating-point types)."""
    if code == "?":
        return rng.random() < 0.5
    size = struct.calcsize("<" + code)
    while True:
        value = struct.unpack("<" + code, rng.randbytes(size))[0]
        if code not in "fd" or math.isfinite(value):
            return value


def _locate(msg: Any, paths: tuple[str, ...]) -> tuple[bytes, str, list, list[int]]:
    """Serialize `msg` and find the byte offset of each of `paths` (see `CdrTemplate`'s notes).

    Returns the serialization, the struct endian prefix, the resolved fields and their offsets.
    Raises `CdrTemplateError` when `paths` repeat or are empty.
    """
    if len(set(paths)) != len(paths):
        raise CdrTemplateError(f"field paths repeat: {paths}")
    if not paths:
        raise CdrTemplateError("no field paths to patch")
    from rclpy.serialization import deserialize_message, serialize_message

    # rmw's buffer may run past the message (a 25-point JointTrajectory: 1684 bytes for 1292, the rest garbage)
    template = serialize_message(msg)[:aligned(_structure(msg)[0], 4)]  # (a payload ends 4-aligned)
    probe = deserialize_message(template, type(msg))  # a copy; `msg` stays as it is
    fields = [_resolve(probe, path) for path in paths]
    endian = "<" if template[1] & 1 else ">"  # CDR encapsulation: odd representation id = little endian
    sizes = [struct.calcsize(endian + field[3]) for field in fields]
    rng = random.Random(0x5EED)
    results: list[tuple[bytes, list[bytes]]] = []  # (serialization, packed sentinel of each field)
    for _ in range(_ROUNDS if min(sizes) > 1 else 16):
        packed = []
        for holder, name, index, code in fields:
            value = _sentinel(code, rng)
            _assign(holder, name, index, value)
            packed.append(struct.pack(endian + code, value))
        data = serialize_message(probe)[:len(template)]
        if len(data) != len(template):
            raise CdrTemplateError(f"field paths {paths}: their values change the serialized length")
        results.append((data, packed))
    base = results[0][0]
    offsets = []
    for i, (path, size) in enumerate(zip(paths, sizes)):
        candidates, off = [], base.find(results[0][1][i])
        while off >= 0:
            if all(data[off:off + size] == packed[i] for data, packed in results):
                candidates.append(off)
            off = base.find(results[0][1][i], off + 1)
        if len(candidates) != 1:
            raise CdrTemplateError(f"field path {path!r}: no unambiguous byte offset ({len(candidates)} candidates)")
        offsets.append(candidates[0])
    return template, endian, fields, offsets


class CdrTemplate:
    """Serialized bytes of a fixed-layout message, rebuilt per sample by patching a few fields in place.

    The template serializes `msg` once (rclpy's ``serialize_message``: the bytes a normal publish sends)
    and `pack` writes the `paths` fields at their offsets with one precompiled `struct.Struct`.

    Parameters
    ----------
    msg
        A message with every constant field set (frame ids, names, covariances, labels, sequence lengths).
        It is not modified.
    paths
        The fields `pack` sets, dotted with element indices, e.g. ``'header.stamp.sec'``, ``'data[1]'``,
        ``'points[3].transforms[0].rotation.w'``: each a fixed-size primitive (numbers, booleans).

    Raises
    ------
    CdrTemplateError
        When a path does not name a fixed-size primitive (a string, a sequence, a nested message, an element
        beyond the template's length), when paths repeat, or when an offset is ambiguous.

    Notes
    -----
    Every string and sequence length is frozen in the template. Each offset is found, not computed: the
    fields are set to random sentinels, twice more, and a field's offset is the one position holding its
    value in every serialization (a byte diff would not do: rmw leaves alignment padding uninitialised).
    """

    def __init__(self, msg: Any, paths: Iterable[str]) -> None:
        self.paths = tuple(paths)
        self.msg_type = type(msg)
        template, endian, fields, offsets = _locate(msg, self.paths)
        order = sorted(range(len(offsets)), key=offsets.__getitem__)
        fmt, end = endian, offsets[order[0]]
        picks: list[int] = []
        gaps: list[bytes] = []
        for i in order:
            if offsets[i] < end:
                raise CdrTemplateError(f"field paths {self.paths[i]!r} and another overlap")
            if offsets[i] > end:
                fmt += f"{offsets[i] - end}s"
                picks.append(len(self.paths) + len(gaps))
                gaps.append(template[end:offsets[i]])
            fmt += fields[i][3]
            picks.append(i)
            end = offsets[i] + struct.calcsize(endian + fields[i][3])
        self.offsets = tuple(offsets)
        self._head, self._tail = template[:offsets[order[0]]], template[end:]
        self._gaps = tuple(gaps)
        self._struct = struct.Struct(fmt)
        self._pick = _getter(picks)
        self.size = len(template)

    def pack(self, *values: Any) -> bytes:
        """The serialized message with the `paths` fields set to `values` (in the order of `paths`).

        Raises
        ------
        CdrTemplateError
            When the number of values is not the number of paths.
        struct.error
            When a value does not fit its field's type (e.g. an integer out of range).
        """
        if len(values) != len(self.paths):
            raise CdrTemplateError(f"{len(values)} values for {len(self.paths)} field paths")
        return b"".join((self._head, self._struct.pack(*self._pick(values + self._gaps)), self._tail))


def _structure(msg: Any) -> tuple[int, list[tuple[int, int]]]:
    """Serialized size and the byte ranges of the length prefixes and strings of `msg` (the module's rules).

    Raises `CdrTemplateError` for field types it does not know (wstring).
    """
    ranges: list[tuple[int, int]] = []
    position = ENCAPSULATION_SIZE

    def item(kind: str, value: Any) -> None:
        nonlocal position
        if kind in _PRIMITIVES:
            size = struct.calcsize("<" + _PRIMITIVES[kind])
            position = aligned(position, size) + size
        elif kind == "string" or kind.startswith("string<"):
            position = aligned(position, 4)
            end = position + 4 + len(value.encode()) + 1
            ranges.append((position, end))
            position = end
        elif hasattr(value, "get_fields_and_field_types"):
            walk(value)
        else:
            raise CdrTemplateError(f"field type {kind!r} is not supported")

    def walk(obj: Any) -> None:
        nonlocal position
        for name, kind in obj.get_fields_and_field_types().items():
            value = getattr(obj, name)
            container = _CONTAINER.match(kind)
            if container is None:
                item(kind, value)
                continue
            if container["seq"]:
                position = aligned(position, 4)
                ranges.append((position, position + 4))
                position += 4
            for element in value:
                item(container["seq"] or container["arr"], element)

    walk(msg)
    return position, ranges


class CdrLayout:
    """Reads fields straight from serialized messages laid out like a template: the reverse of `CdrTemplate`.

    `read` takes the fields with one precompiled `struct.Struct` when the bytes have the template's layout,
    and returns None otherwise (the caller falls back to a general decoder).

    Parameters
    ----------
    msg
        A message with the layout to recognise: its strings (frame ids,
        names) and sequence lengths are what incoming bytes must repeat.
    paths
        The fields `read` returns, as in `CdrTemplate`.

    Raises
    ------
    CdrTemplateError
        As `CdrTemplate` does for bad paths (a layout computed too short from the
        field types fails there: rclpy cannot read the template back).

    Notes
    -----
    The layout is the template's encapsulation header, strings (length and bytes) and sequence counts
    (`_structure`): bytes of the same length that repeat them have every field at the template's offset,
    whatever their padding; any other bytes are refused (None), never misread.
    """

    def __init__(self, msg: Any, paths: Iterable[str]) -> None:
        self.paths = tuple(paths)
        template, endian, fields, offsets = _locate(msg, self.paths)
        size, ranges = _structure(msg)
        items: list[tuple[int, int, str | int]] = [(0, 4, "s"), *((a, b, "s") for a, b in ranges)]  # "s": structure
        items += [(off, off + struct.calcsize(endian + field[3]), i)
                  for i, (off, field) in enumerate(zip(offsets, fields))]
        items.sort()
        fmt, position, structure, picks = endian, 0, [], [0] * len(fields)
        for index, (start, end, what) in enumerate(items):
            if start < position:
                raise CdrTemplateError(f"field paths {self.paths}: a field overlaps a string or sequence count")
            if start > position:
                fmt += f"{start - position}x"
            if isinstance(what, str):  # the header, a string or a sequence count
                fmt += f"{end - start}s"
                structure.append(index)
            else:
                fmt += fields[what][3]
                picks[what] = index
            position = end
        self._struct = struct.Struct(fmt + (f"{size - position}x" if size > position else ""))
        self._structure = _getter(structure)
        self._expected = tuple(template[start:end] for start, end, what in items if what == "s")
        self._pick = _getter(picks)
        self.size = size

    def read(self, data: bytes) -> tuple | None:
        """The values of the `paths` fields (in that order), or None when `data` is not laid out like the template."""
        if len(data) != self.size:
            return None
        values = self._struct.unpack(data)
        if self._structure(values) != self._expected:
            return None
        return self._pick(values)


def _getter(indices: list[int]) -> Callable[[tuple], tuple]:
    """`itemgetter` that returns a tuple also for one index."""
    if len(indices) == 1:
        index = indices[0]
        return lambda values: (values[index],)
    return itemgetter(*indices)


class _Unreadable(ValueError):
    """Bytes the report's readers do not walk (not little-endian CDR, or truncated)."""


def _count(data: bytes, pos: int) -> tuple[int, int]:
    """(uint32 at `pos` aligned to 4, the position after it)."""
    pos = aligned(pos, 4)
    return _UINT32.unpack_from(data, pos)[0], pos + 4


def _skip_string(data: bytes, pos: int) -> int:
    return sum(_count(data, pos))


def _string(data: bytes, pos: int) -> tuple[str, int]:
    length, pos = _count(data, pos)
    if length == 0 or pos + length > len(data):
        raise _Unreadable("a string past the end of the message")
    return data[pos : pos + length - 1].decode(), pos + length  # without the terminating NUL


def _header(data: bytes) -> tuple[int, int]:
    """(std_msgs/Header stamp [ns], the position after its frame_id)."""
    if data[:2] not in _LITTLE_ENDIAN:
        raise _Unreadable("not little-endian CDR")
    sec, nanosec = _STAMP.unpack_from(data, ENCAPSULATION_SIZE)
    return sec * 1_000_000_000 + nanosec, _skip_string(data, 12)


def _pose_after(data: bytes, pos: int) -> tuple[float, float, float]:
    x, y, _, qx, qy, qz, qw = _POSE.unpack_from(data, aligned(pos, 8))
    return (x, y, yaw_of(qx, qy, qz, qw))


def odometry_pose(data: bytes) -> tuple[int, tuple[float, float, float]]:
    """nav_msgs/Odometry bytes -> (header stamp [ns], (x, y, yaw) of pose.pose)."""
    stamp, pos = _header(data)
    return stamp, _pose_after(data, _skip_string(data, pos))  # child_frame_id, then the pose


def preview_start(data: bytes) -> tuple[int, tuple[float, float, float] | None]:
    """MultiDOFJointTrajectory bytes -> (header stamp [ns], (x, y, yaw) of point 0's first transform or None)."""
    stamp, pos = _header(data)
    names, pos = _count(data, pos)
    for _ in range(names):
        pos = _skip_string(data, pos)
    points, pos = _count(data, pos)
    if points == 0:
        return stamp, None
    transforms, pos = _count(data, pos)
    return stamp, (_pose_after(data, pos) if transforms else None)


def float64_array(data: bytes) -> tuple[float, ...]:
    """std_msgs/Float64MultiArray bytes -> its data (any count)."""
    if data[:2] not in _LITTLE_ENDIAN:
        raise _Unreadable("not little-endian CDR")
    dims, pos = _count(data, ENCAPSULATION_SIZE)
    for _ in range(dims):
        pos = aligned(_skip_string(data, pos), 4) + 8  # label, then size and stride (uint32)
    count, pos = _count(data, aligned(pos, 4) + 4)  # data_offset, then data's count
    return struct.unpack_from(f"<{count}d", data, aligned(pos, 8)) if count else ()


def diagnostics_with(key: str) -> Callable[[bytes], tuple[int, dict[str, str] | None]]:
    """A reader of DiagnosticArray bytes -> (header stamp [ns], the first status's key-values that hold `key`)."""

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


def values_of(data: bytes, read: Callable[[bytes], Any], of_message: Callable[[Any], Any],
              decode: Callable[[], Any]) -> Any:
    """`read(data)`, else `of_message(decode())` for bytes `read` does not walk (`decode` raises as it will).

    `of_message` takes the same values from a decoded message (`ros.decode`'s ``*_of_message`` functions).
    """
    try:
        return read(data)
    except (_Unreadable, struct.error, IndexError, UnicodeDecodeError):
        return of_message(decode())
