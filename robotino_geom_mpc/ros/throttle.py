"""Throttled log messages whose suppressed calls cost a dictionary lookup, not rclpy's caller search.

rclpy's own ``throttle_duration_sec`` identifies the call site on every call, suppressed or not, with
`inspect.getframeinfo` and `os.path.realpath` up the stack (about a millisecond): a warning that fires every
tick while a fault lasts (a stale preview, refused commands) then costs the loop its deadline, which makes
the fault worse. `warn_throttled` and `info_throttled` check the period first, per logger and call site,
and call the logger only for the messages that go out.
"""

from __future__ import annotations

import sys
import time
from typing import Any

__all__ = ["error_throttled", "info_throttled", "log_throttled", "warn_throttled"]

_LAST_S: dict[tuple[str, object, int], float] = {}  # (logger name, caller's code, line) -> last time logged
_LAST_KEY_S: dict[tuple[str, str], float] = {}  # (logger name, key) -> last time logged


def _due(logger: Any, period_s: float) -> bool:
    frame = sys._getframe(2)  # the caller of warn_throttled / info_throttled
    site = (logger.name, frame.f_code, frame.f_lineno)
    now = time.monotonic()
    last = _LAST_S.get(site)
    if last is not None and now - last < period_s:
        return False
    _LAST_S[site] = now
    return True


def warn_throttled(logger: Any, message: str, period_s: float = 1.0) -> None:
    """`logger.warn(message)` at most once per `period_s` [s] from this call site."""
    if _due(logger, period_s):
        logger.warn(message)


def info_throttled(logger: Any, message: str, period_s: float = 1.0) -> None:
    """`logger.info(message)` at most once per `period_s` [s] from this call site."""
    if _due(logger, period_s):
        logger.info(message)


def error_throttled(logger: Any, message: str, period_s: float = 1.0) -> None:
    """`logger.error(message)` at most once per `period_s` [s] from this call site."""
    if _due(logger, period_s):
        logger.error(message)


def log_throttled(logger: Any, level: str, message: str, period_s: float, key: str) -> None:
    """`logger.<level>(message)` (``INFO``, ``WARN``, ``ERROR``; ``OK`` logs as info) at most once per `period_s`
    [s] per `key` (a loop's log line names its own key); `period_s` 0: every time.
    """
    if period_s > 0.0:
        now = time.monotonic()
        last = _LAST_KEY_S.get((logger.name, key))
        if last is not None and now - last < period_s:
            return
        _LAST_KEY_S[(logger.name, key)] = now
    if level == "WARN":  # one call site per severity (rclpy refuses a site whose severity changes)
        logger.warn(message)
    elif level == "ERROR":
        logger.error(message)
    else:
        logger.info(message)
