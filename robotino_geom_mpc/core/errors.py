"""The package's one error base class and the one array check every module uses at its boundary."""

from __future__ import annotations

import numpy as np

__all__ = ["RobotinoError", "checked_array"]


class RobotinoError(Exception):
    """Base of every error the package raises on purpose: bad parameters, inputs, files, runs.

    Each module keeps its own subclass (e.g. `core.params.ParamError`), so a
    caller can catch one module's errors, or all of the package's with this class.
    """


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
