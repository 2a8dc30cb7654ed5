"""CDR bytes without rclpy's Python conversion: templates patched per sample, layouts read in place, a general decoder.

rclpy's conversions between Python messages and CDR cost far more than the
control step, so the loop's messages travel as bytes: `CdrTemplate`
serializes a fixed-layout message once and patches its numbers per sample
(publishers), `CdrLayout` reads the numbers straight from bytes laid out like
a template and returns None for any other layout, which then goes to the
general decoder (`cdr_reader`, rclpy's). `bench --json` times both against rclpy's own
(de)serialization (``cdr_*`` keys).
"""

from __future__ import annotations

import math
import random
import re
import struct
from collections.abc import Callable, Iterable
from operator import itemgetter
from typing import Any

from rclpy.serialization import deserialize_message, serialize_message

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["CdrLayout", "CdrTemplate", "CdrTemplateError", "MalformedMessage", "cdr_reader", "field_setter"]

class MalformedMessage(RobotinoError, ValueError):
    """Serialized bytes that do not decode as the expected message type."""


def cdr_reader(msg_type: type, type_name: str) -> Callable[[bytes], Any]:
    """A decoder of serialized `msg_type` messages (e.g. ``"nav_msgs/msg/Odometry"`` for `type_name`).

    rclpy's `deserialize_message`: the nodes' fallback for a layout `CdrLayout` does not read, rare enough
    that its speed does not matter, and free to import (rosbags' faster generated readers cost a node
    0.3-0.5 s of import at start). Undecodable bytes raise `MalformedMessage`.
    """

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


def field_setter(msg: Any, paths: Iterable[str]) -> Callable[[Iterable[Any]], None]:
    """A function setting the `paths` fields of `msg` (as in `CdrTemplate`) to given values, resolved once.

    The peer of `CdrTemplate.pack` on a Python message (what the benchmark times it against).
    Raises `CdrTemplateError` for a path that does not name a fixed-size primitive.
    """
    fields = [_resolve(msg, path)[:3] for path in paths]

    def set_fields(values: Iterable[Any]) -> None:
        for (holder, name, index), value in zip(fields, values):
            _assign(holder, name, index, value)

    return set_fields


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
    template = serialize_message(msg)
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
        data = serialize_message(probe)
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

    rclpy's conversion of a Python message to C costs far more than the DDS
    write itself; ``Publisher.publish`` also takes the serialized bytes. The
    template serializes `msg` once (``rclpy.serialization.serialize_message``,
    so the bytes are those the normal publish would send) and `pack` writes
    new values of the `paths` fields at their offsets with one precompiled
    `struct.Struct`.

    Parameters
    ----------
    msg
        A message with every constant field set (frame ids, names, covariances,
        layout labels, sequence lengths). It is not modified.
    paths
        The fields `pack` sets, dotted with element indices, e.g.
        ``'header.stamp.sec'``, ``'pose.pose.position.x'``, ``'data[1]'``,
        ``'points[3].transforms[0].rotation.w'``. Each must be a fixed-size
        primitive (numbers, booleans).

    Raises
    ------
    CdrTemplateError
        When a path does not name a fixed-size primitive (a string, a whole
        sequence, a nested message, an element beyond the template's length),
        when paths repeat, or when a field's byte offset cannot be determined
        unambiguously.

    Notes
    -----
    Only fixed-layout samples qualify: every string and sequence length is
    frozen in the template, so a message whose variable-length fields change
    from sample to sample cannot be templated. Each offset is found, not
    computed: the patched fields are set to random sentinel values, and again
    to others, and a field's offset is the one position holding its value in
    each of these serializations. (A byte diff would
    not do: the serializer leaves alignment padding uninitialised, so padding
    bytes differ between calls; the template keeps those of its one call,
    which no reader looks at.)
    """

    def __init__(self, msg: Any, paths: Iterable[str]) -> None:
        self.paths = tuple(paths)
        self.msg_type = type(msg)
        template, endian, fields, offsets = _locate(msg, self.paths)
        order = sorted(range(len(offsets)), key=offsets.__getitem__)
        fmt, picks, gaps, end = endian, [], [], offsets[order[0]]
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
        self._pick = itemgetter(*picks) if len(picks) > 1 else lambda values: (values[picks[0]],)
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
    """Serialized size and the byte ranges of the length prefixes and strings of `msg` (plain CDR, XCDR1).

    Walks the fields as the serializer lays them out: after the 4-byte
    encapsulation header, each primitive aligned to its size, a string as a
    4-aligned uint32 length plus its bytes and a NUL, a sequence as a
    4-aligned uint32 count plus its elements, an array as its elements.
    Raises `CdrTemplateError` for field types it does not know (wstring).
    """
    ranges: list[tuple[int, int]] = []
    position = 4

    def align(size: int) -> None:
        nonlocal position
        position += -(position - 4) % size

    def item(kind: str, value: Any) -> None:
        nonlocal position
        if kind in _PRIMITIVES:
            size = struct.calcsize("<" + _PRIMITIVES[kind])
            align(size)
            position += size
        elif kind == "string" or kind.startswith("string<"):
            align(4)
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
                align(4)
                ranges.append((position, position + 4))
                position += 4
            for element in value:
                item(container["seq"] or container["arr"], element)

    walk(msg)
    return position, ranges


class CdrLayout:
    """Reads fields straight from serialized messages laid out like a template: the reverse of `CdrTemplate`.

    Decoding a whole message into Python objects costs far more than the
    few fields a node needs. `read` takes them with one precompiled
    `struct.Struct` when the bytes have the template's layout, and returns
    None otherwise, so that the caller falls back to a general decoder.

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
        As `CdrTemplate` does for bad paths, and when the layout computed from
        the field types disagrees with rclpy's serialization.

    Notes
    -----
    The layout is the template's structure: its encapsulation header, every
    string (length and bytes) and every sequence count (`_structure`).
    Bytes of the same length that repeat it have every field at the
    template's offset, whatever their numbers and alignment padding; any
    other bytes are refused (None), never misread.
    """

    def __init__(self, msg: Any, paths: Iterable[str]) -> None:
        self.paths = tuple(paths)
        template, endian, fields, offsets = _locate(msg, self.paths)
        size, ranges = _structure(msg)
        if size != len(template):
            raise CdrTemplateError(f"computed layout of {type(msg).__name__} ({size} bytes) disagrees with its "
                                   f"serialization ({len(template)} bytes)")
        items = [(0, 4, "s")] + [(a, b, "s") for a, b in ranges]
        items += [(off, off + struct.calcsize(endian + field[3]), i)
                  for i, (off, field) in enumerate(zip(offsets, fields))]
        items.sort()
        fmt, position, structure, picks = endian, 0, [], [0] * len(fields)
        for index, (start, end, what) in enumerate(items):
            if start < position:
                raise CdrTemplateError(f"field paths {self.paths}: a field overlaps a string or sequence count")
            if start > position:
                fmt += f"{start - position}x"
            if what == "s":
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
