"""The array helpers the modules share: the check at their boundary (shape and finiteness, named in the error)
and the largest |value| over three columns (the array forms' batch axis).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import SupportsFloat

import numpy as np

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["checked_array", "float_triple", "largest_abs"]


def checked_array(
    value: object, shape: tuple[int, ...], name: str, error: type[Exception] = RobotinoError, *, finite: bool = True
) -> np.ndarray:
    """`value` as a float array of `shape`, else `error` naming `name`, the expected and the actual shape.

    Parameters
    ----------
    value
        Anything `numpy.asarray` takes.
    shape
        The expected shape, e.g. ``(3,)``.
    name
        The argument's name, used in the message.
    error
        The exception class to raise (the caller module's own error class).
    finite
        Also refuse NaN and infinities.

    Raises
    ------
    error
        For a value that does not convert, has another shape, or (with `finite`) a non-finite entry.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise error(f"{name} must be an array of shape {shape}: {exc}") from None
    if arr.shape != tuple(shape):
        raise error(f"{name} must have shape {tuple(shape)}, got {arr.shape}")
    if finite and not np.isfinite(arr).all():
        raise error(f"{name} must be finite, got {arr.tolist()}")
    return arr


def float_triple(values: Iterable[SupportsFloat]) -> tuple[float, float, float]:
    """Three values (a twist, three wheel voltages, a pose) as a tuple of three Python floats.

    Raises
    ------
    ValueError
        For more or fewer than three values (callers check lengths first where the input is outside data).
    """
    x, y, z = values
    return float(x), float(y), float(z)


def largest_abs(values: np.ndarray) -> np.ndarray:
    """max |v| over the last axis of length 3, shape (...,): three columns compared (numpy's reduction over a
    last axis this short costs about six times as much at a batch of 500 rows).
    """
    magnitudes = np.abs(values)
    return np.maximum(np.maximum(magnitudes[..., 0], magnitudes[..., 1]), magnitudes[..., 2])
