"""The package's one error base class: every error it raises on purpose derives from it."""

from __future__ import annotations

__all__ = ["RobotinoError"]


class RobotinoError(Exception):
    """Base of every error the package raises on purpose: bad parameters, inputs, files, runs.

    Each module keeps its own subclass (e.g. `params.specs.ParamError`), so a
    caller can catch one module's errors, or all of the package's with this class.
    """
