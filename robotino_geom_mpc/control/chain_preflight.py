"""The dry run before the first motion (`robotino-geom-mpc preflight`): the driver chain there and as configured.

Plain checks over what a listener saw while nothing commanded the robot: the ROS graph's endpoints, and the
odometry messages as (stamp, receive time, pose, twist). Each check gives one `Check` (name, passed, the measured
figure). Against the chain parameters (`model.driver_chain.ChainParams`: the controller's ``chain.*``, and
`identify`'s file over them):

``odom publisher``    exactly one publisher of the odometry topic (the driver's; two are a fault)
``cmd_vel subscriber`` at least one subscriber of the command topic (the driver takes the controller's twists)
``odometry rate``     messages per second of stamp time, against ``odometry_rate_hz`` (dispatch ``all``; ``latest``:
                      the rate of the passes that carry a sample), within `RATE_TOLERANCE`
``dispatch rate``     distinct stamps per second (the driver's passes that dispatched a sample) against
                      min(``driver_rate_hz``, ``odometry_rate_hz``), within `RATE_TOLERANCE`
``stamp pattern``     the stamps fit the chain's 30 Hz / 50 Hz dispatch pattern: `control.measurement_times`'s
                      `MeasurementClock` (the firmware's grid seen through the driver's passes, with the link's
                      delay and jitter) keeps one grid offset for every message (no restart)
``stamps monotonic``  no stamp older than one received before it
``stamps fresh``      the median age (receive time - stamp, one clock: the driver beside this listener) within
                      [-`FUTURE_S`, `STALE_S`] (the controller's default ``future_tolerance_s`` and
                      ``odom_timeout_s``), and the last message not older than `STALE_S` when the listening ended
``at rest``           every twist component within `MOVING` and the pose within `REST_POSE` over the listening
``dead time``         (with `identify`'s file) its round trip 2 ``chain.link.delay_s`` is within [0, the motor
                      timeout), and the pattern check passes with its jitter: the identified chain explains the
                      dispatch seen now. The dead time itself needs motion to be measured (`identify` does).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from robotino_geom_mpc.control.measurement_times import MeasurementClock
from robotino_geom_mpc.model.driver_chain import ChainParams

__all__ = ["Check", "FUTURE_S", "MOVING", "OdometrySample", "RATE_TOLERANCE", "REST_POSE", "STALE_S",
           "dead_time_check", "graph_checks", "odometry_checks"]

RATE_TOLERANCE = 0.1  # relative
STALE_S = 0.1  # the controller's odom_timeout_s default
FUTURE_S = 0.05  # the controller's future_tolerance_s default
MOVING = 1e-3  # a twist component above this [m/s, rad/s] is motion (as `recording.odometry_timing`)
REST_POSE = (1e-3, 1e-3)  # largest pose spread at rest: position [m], heading [rad]
MIN_MESSAGES = 10  # fewer: no odometry to speak of


class OdometrySample(NamedTuple):
    """One odometry message as a listener got it: header stamp and receive time [s] (the same clock), pose (x, y,
    theta) in odom and twist (v_x, v_y, theta') in base_link.
    """

    stamp_s: float
    received_s: float
    pose: tuple[float, float, float]
    twist: tuple[float, float, float]


class Check(NamedTuple):
    """A check's name, its verdict and the measured figure behind it (one line)."""

    name: str
    passed: bool
    figure: str

    def line(self) -> str:
        """``PASS  name: figure`` (or FAIL)."""
        return f"{'PASS' if self.passed else 'FAIL'}  {self.name}: {self.figure}"


def graph_checks(odom_topic: str, odom_publishers: Sequence[str], cmd_vel_topic: str,
                 cmd_vel_subscribers: Sequence[str]) -> list[Check]:
    """Exactly one publisher of `odom_topic`, at least one subscriber of `cmd_vel_topic` (node names)."""
    listed = ", ".join(odom_publishers) or "none"
    return [Check("odom publisher", len(odom_publishers) == 1, f"{len(odom_publishers)} on {odom_topic} ({listed})"),
            Check("cmd_vel subscriber", len(cmd_vel_subscribers) >= 1,
                  f"{len(cmd_vel_subscribers)} on {cmd_vel_topic} ({', '.join(cmd_vel_subscribers) or 'none'})")]


def _rate(count: int, span_s: float) -> float:
    return count / span_s if span_s > 0.0 else math.nan


def _within(value: float, expected: float) -> bool:
    return math.isfinite(value) and abs(value - expected) <= RATE_TOLERANCE * expected


def _restarts(stamps: Sequence[float], chain: ChainParams) -> tuple[int, float]:
    """`MeasurementClock` restarts over `stamps` and its final grid offset's half-uncertainty [s]."""
    clock = MeasurementClock(chain.odometry_period_s, chain.driver_period_s, chain.link_delay_s, chain.link_jitter_s,
                             chain.odometry_dispatch == "latest")
    for stamp in stamps:
        clock.update(stamp)
    return clock.restarts, 0.5 * (clock.hi - clock.lo)


def odometry_checks(samples: Sequence[OdometrySample], chain: ChainParams, end_s: float) -> list[Check]:
    """The odometry's checks (module docstring) over `samples` in arrival order; `end_s` the end of the listening
    (receive clock).
    """
    n = len(samples)
    if n < MIN_MESSAGES:
        figure = f"{n} odometry messages (fewer than {MIN_MESSAGES})"
        return [Check(name, False, figure) for name in ("odometry rate", "dispatch rate", "stamp pattern",
                                                        "stamps monotonic", "stamps fresh", "at rest")]
    stamps = np.array([s.stamp_s for s in samples])
    received = np.array([s.received_s for s in samples])
    distinct = np.unique(stamps)
    span = float(distinct[-1] - distinct[0])
    message_rate = _rate(int(np.sum(stamps > distinct[0])), span)  # the messages after the first stamp's
    dispatch_rate = _rate(len(distinct) - 1, span)
    pass_rate = min(chain.driver_rate_hz, chain.odometry_rate_hz)
    expected = chain.odometry_rate_hz if chain.odometry_dispatch == "all" else pass_rate
    checks = [
        Check("odometry rate", _within(message_rate, expected), f"{message_rate:.1f} Hz of stamp time ({n} messages;"
              f" chain: {expected:g} Hz, dispatch {chain.odometry_dispatch})"),
        Check("dispatch rate", _within(dispatch_rate, pass_rate), f"{dispatch_rate:.1f} Hz ({len(distinct)} distinct "
              f"stamps; chain: {pass_rate:g} Hz)"),
    ]
    older = int(np.sum(stamps < np.maximum.accumulate(stamps)))
    if older:
        checks.append(Check("stamp pattern", False, "not checked: stamps out of order"))
    else:
        restarts, uncertainty = _restarts(stamps.tolist(), chain)
        checks.append(Check("stamp pattern", restarts == 0, f"{restarts} restarts of the firmware grid over {n} "
                            f"messages (grid offset +-{1e3 * uncertainty:.1f} ms; chain: {chain.odometry_rate_hz:g} Hz "
                            f"odometry, {chain.driver_rate_hz:g} Hz driver, jitter {1e3 * chain.link_jitter_s:g} ms)"))
    checks.append(Check("stamps monotonic", older == 0, f"{older} of {n} stamps older than one before"))
    age = received - stamps
    median = float(np.median(age))
    last = float(end_s - received[-1])
    checks.append(Check("stamps fresh", -FUTURE_S <= median <= STALE_S and last <= STALE_S,
                        f"age median {1e3 * median:.1f} ms, max {1e3 * float(age.max()):.1f} ms (allowed "
                        f"{-1e3 * FUTURE_S:g}..{1e3 * STALE_S:g} ms); last message {1e3 * last:.0f} ms before the end"))
    twist = np.abs(np.array([s.twist for s in samples])).max()
    pose = np.array([s.pose for s in samples])
    spread = pose.max(axis=0) - pose.min(axis=0)
    position = float(np.hypot(spread[0], spread[1]))
    rest = twist <= MOVING and position <= REST_POSE[0] and spread[2] <= REST_POSE[1]
    checks.append(Check("at rest", bool(rest), f"largest twist component {float(twist):.2g} (allowed {MOVING:g}), "
                        f"pose spread {1e3 * position:.2f} mm, {1e3 * float(spread[2]):.2f} mrad"))
    return checks


def dead_time_check(samples: Sequence[OdometrySample], identified: ChainParams) -> Check:
    """The identified round trip plausible and the identified chain explaining the dispatch (module docstring)."""
    round_trip = 2.0 * identified.link_delay_s
    plausible = 0.0 <= round_trip < identified.motor_timeout_s
    stamps = [s.stamp_s for s in samples]
    if len(stamps) < MIN_MESSAGES or any(b < a for a, b in zip(stamps, stamps[1:])):
        return Check("dead time", False, f"identified round trip {1e3 * round_trip:.1f} ms; not checked against the "
                     f"dispatch: too few or out-of-order stamps")
    restarts, _ = _restarts(stamps, identified)
    return Check("dead time", plausible and restarts == 0, f"identified round trip {1e3 * round_trip:.1f} ms (motor "
                 f"timeout {1e3 * identified.motor_timeout_s:g} ms), jitter {1e3 * identified.link_jitter_s:g} ms: "
                 f"{restarts} restarts of the dispatch pattern")
