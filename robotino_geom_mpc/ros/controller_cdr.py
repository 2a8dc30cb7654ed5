"""The controller's status written as CDR bytes directly (rclpy's conversion costs per tick).

`diagnostics_cdr`: the controller's DiagnosticArray (one status named `STATUS_NAME`), published by
`nodes.controller_outputs` (its ``predicted_path``: `ros.messages.path_cdr`).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

__all__ = ["STATUS_NAME", "diagnostics_cdr"]

STATUS_NAME = "robotino_geom_mpc: controller"


_U32 = struct.Struct("<I")
_HEADER = struct.Struct("<4siIIb")  # encapsulation (CDR little endian), stamp, frame_id "" (length 1), its NUL
_ONE_STATUS = _U32.pack(1)
_STATUS_NAME = STATUS_NAME.encode()


def _put_string(out: bytearray, text: bytes) -> None:
    """Append a CDR string (aligned length with the NUL, the bytes, the NUL) to `out` (4 encapsulation bytes first)."""
    out += b"\0" * (-len(out) % 4)
    out += _U32.pack(len(text) + 1)
    out += text
    out += b"\0"


def diagnostics_cdr(stamp: int, level: bytes, message: str, keys: Sequence[bytes], values: Sequence[str]) -> bytes:
    """The serialized DiagnosticArray of the controller's status (frame "", one status named `STATUS_NAME`,
    hardware ``robotino``) with header stamp `stamp` [ns], `level`, `message` and the pairs `keys` (UTF-8) / `values`.

    Plain CDR (XCDR1, little endian) written directly: rclpy's conversion of the 15 key-value pairs cost ~70 us a
    tick, this ~15 us (strings change length, so a `CdrTemplate` cannot serve).
    """
    out = bytearray(_HEADER.pack(b"\0\1\0\0", *divmod(stamp, 1_000_000_000), 1, 0))
    out += b"\0" * (-len(out) % 4)
    out += _ONE_STATUS
    out += level
    _put_string(out, _STATUS_NAME)
    _put_string(out, message.encode())
    _put_string(out, b"robotino")
    out += b"\0" * (-len(out) % 4)
    out += _U32.pack(len(keys))
    for key, value in zip(keys, values):
        _put_string(out, key)
        _put_string(out, value.encode())
    return bytes(out)
