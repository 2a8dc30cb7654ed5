"""Throttled log messages whose suppressed calls cost a dictionary lookup, not rclpy's caller search.

rclpy's own ``throttle_duration_sec`` identifies the call site on every call, suppressed or not, with
`inspect.getframeinfo` and `os.path.realpath` up the stack (about a millisecond): a warning that fires every
tick while a fault lasts (a stale preview, refused commands) then costs the loop its deadline, which makes
the fault worse. `warn_throttled` and `info_throttled` check the period first, per logger and call site,
and call the logger only for the messages that go out. Those go straight to rcutils with the caller's
function, file and line read off its frame (what rclpy's search finds for them): ~10 us instead of
0.35-1 ms, which a fleet's process pays per robot (N robots' "bumpless restart" lines as their references
start, a fault's warnings).
"""

from __future__ import annotations

import sys
import time
from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.logging import LoggingSeverity

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


def _log(logger: Any, severity: LoggingSeverity, message: str) -> None:
    """`message` at `severity` from the caller of this module's public function: an rclpy logger's straight to
    rcutils (module docstring), any other's through its method of that severity.
    """
    if not isinstance(logger, RcutilsLogger):
        getattr(logger, severity.name.lower())(message)
        return
    if logger.is_enabled_for(severity):
        frame = sys._getframe(2)
        _rclpy.rclpy_logging_rcutils_log(severity, logger.name, message, frame.f_code.co_name,
                                         frame.f_code.co_filename, frame.f_lineno)


def warn_throttled(logger: Any, message: str, period_s: float = 1.0) -> None:
    """`logger.warn(message)` at most once per `period_s` [s] from this call site."""
    if _due(logger, period_s):
        _log(logger, LoggingSeverity.WARN, message)


def info_throttled(logger: Any, message: str, period_s: float = 1.0) -> None:
    """`logger.info(message)` at most once per `period_s` [s] from this call site."""
    if _due(logger, period_s):
        _log(logger, LoggingSeverity.INFO, message)


def error_throttled(logger: Any, message: str, period_s: float = 1.0) -> None:
    """`logger.error(message)` at most once per `period_s` [s] from this call site."""
    if _due(logger, period_s):
        _log(logger, LoggingSeverity.ERROR, message)


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
    _log(logger, LoggingSeverity.WARN if level == "WARN" else LoggingSeverity.ERROR if level == "ERROR" else
         LoggingSeverity.INFO, message)
