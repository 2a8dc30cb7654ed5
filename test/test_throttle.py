"""`ros.throttle`: at most one message per period and call site, the period checked before the logger is called."""

import pytest

from robotino_geom_mpc.ros import throttle
from robotino_geom_mpc.ros.throttle import info_throttled, warn_throttled

pytestmark = pytest.mark.unit


class _Logger:
    def __init__(self, name: str) -> None:
        self.name, self.lines = name, []

    def warn(self, message: str) -> None:
        self.lines.append(("warn", message))

    def info(self, message: str) -> None:
        self.lines.append(("info", message))


@pytest.fixture
def clock(monkeypatch):
    now = [1000.0]
    monkeypatch.setattr(throttle.time, "monotonic", lambda: now[0])
    monkeypatch.setattr(throttle, "_LAST_S", {})
    return now


def _tick(logger: _Logger, k: int) -> None:
    warn_throttled(logger, f"warn {k}", 1.0)  # one call site ...


def _other_site(logger: _Logger, k: int) -> None:
    info_throttled(logger, f"info {k}", 0.25)  # ... and another, with its own period


def test_one_message_per_period_per_site_and_logger(clock):
    a, b = _Logger("a"), _Logger("b")
    for k in range(256):  # 2 s at 128 Hz (steps exact in binary)
        _tick(a, k)
        _tick(b, k)
        _other_site(a, k)
        clock[0] += 1 / 128
    # a message goes out at t = 0 and then at the first call at least a period after the last one out
    assert [m for kind, m in a.lines if kind == "warn"] == ["warn 0", "warn 128"]
    assert [m for kind, m in b.lines if kind == "warn"] == ["warn 0", "warn 128"]
    assert [m for kind, m in a.lines if kind == "info"] == [f"info {k}" for k in range(0, 256, 32)]


def test_suppressed_calls_do_not_reach_the_logger(clock):
    class Counting(_Logger):
        def warn(self, message: str) -> None:
            raise AssertionError("called within the period")

    logger = Counting("c")
    throttle._LAST_S[(logger.name, _tick.__code__, _tick.__code__.co_firstlineno + 1)] = clock[0]
    for k in range(50):
        _tick(logger, k)
        clock[0] += 0.01


def test_an_rclpy_loggers_message_reaches_rcutils_with_its_call_site(capfd, clock):
    """An rclpy logger's messages go straight to rcutils (not through rclpy's caller search): the console line
    carries the severity, the logger's name and the message; a suppressed one is not there.
    """
    import rclpy.logging

    logger = rclpy.logging.get_logger("throttle_test")
    _tick(logger, 7)
    _tick(logger, 8)  # suppressed: within the period
    _other_site(logger, 9)
    err = capfd.readouterr().err
    assert "[WARN]" in err and "[throttle_test]: warn 7" in err and "warn 8" not in err
    assert "[INFO]" in err and "[throttle_test]: info 9" in err
