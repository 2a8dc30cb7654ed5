"""The timing of a recording's odometry and commands: what a report without ground truth says about the chain.

A real robot's odometry comes through its driver: stamped when the driver dispatched it, several samples under one
stamp (the robocup-logistics driver's passes at 30 Hz dispatch the firmware's 50 Hz samples, one or two a pass;
`model.driver_chain`). From the recorded ``odom`` and ``cmd_vel`` alone (`odometry_timing`):

* ``odometry_messages``, ``odometry_stamps`` (distinct) and ``samples_per_stamp`` (how many stamps carried 1, 2,
  ... messages: the dispatch pattern);
* ``stamp_interval_ms`` (median, p99, max) between distinct stamps, and ``stamp_rate_hz`` (1 / median);
* ``stamps_out_of_order``: messages whose stamp is older than one received before;
* ``odometry_age_ms`` (median, p99, max): the recorder's receive time - stamp, for a realtime run (None in
  lockstep, where stamps are sim time);
* ``commands`` (``cmd_vel`` messages) and ``command_interval_ms`` (median, p99, max);
* ``first_response_ms``: from the first non-zero ``cmd_vel`` (its publish time) to the stamp of the first odometry
  after it that moves (a twist component above 1 mm/s or 1 mrad/s): the command path's dead time plus the ramp's
  first steps, as the recording shows it; None when not measurable (no non-zero command, or no motion after it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.definitions import _typestore
from robotino_geom_mpc.ros.decode import stamp_ns

__all__ = ["MOVING", "odometry_timing", "timing_line"]

MOVING = 1e-3  # a twist component above this [m/s, rad/s] is motion (first_response_ms)


def _ms(values: np.ndarray) -> dict[str, float] | None:
    if values.size == 0:
        return None
    a = 1e3 * values
    return {"median": float(np.median(a)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def odometry_timing(bag: BagReader, odom_topic: str, cmd_topic: str | None, lockstep: bool) -> dict[str, Any]:
    """The timing figures of the module docstring from the recorded ``odom`` and ``cmd_vel``."""
    store = _typestore()
    odom = []  # (log time, publish time, stamp, moving)
    for m in bag.messages([odom_topic]):
        msg: Any = store.deserialize_cdr(m.data, m.type)
        t = msg.twist.twist
        moving = max(abs(t.linear.x), abs(t.linear.y), abs(t.angular.z)) > MOVING
        odom.append((m.log_time_ns, m.publish_time_ns, stamp_ns(msg.header.stamp), moving))
    odom.sort(key=lambda item: item[0])
    counts: dict[int, int] = {}
    first_log: dict[int, int] = {}
    out_of_order, newest = 0, None
    for log, _, stamp, _ in odom:
        counts[stamp] = counts.get(stamp, 0) + 1
        first_log.setdefault(stamp, log)
        if newest is not None and stamp < newest:
            out_of_order += 1
        newest = stamp if newest is None else max(newest, stamp)
    stamps = np.array(sorted(counts), dtype=np.int64)
    intervals = np.diff(stamps) * 1e-9
    pattern: dict[str, int] = {}
    for n in counts.values():
        pattern[str(n)] = pattern.get(str(n), 0) + 1
    commands = []  # (publish time, non-zero)
    for m in bag.messages([cmd_topic] if cmd_topic else []):
        msg = store.deserialize_cdr(m.data, m.type)  # (Any, as above)
        commands.append((m.publish_time_ns, any(v != 0.0 for v in (msg.linear.x, msg.linear.y, msg.angular.z))))
    commands.sort()
    command_times = np.array([p for p, _ in commands], dtype=np.int64)
    response = None
    first = next((p for p, nonzero in commands if nonzero), None)
    if first is not None:
        moved = [stamp for _, _, stamp, moving in odom if moving and stamp > first]
        response = (min(moved) - first) * 1e-6 if moved else None  # ns -> ms
    return {
        "odometry_messages": len(odom),
        "odometry_stamps": int(stamps.size),
        "samples_per_stamp": dict(sorted(pattern.items(), key=lambda item: int(item[0]))),
        "stamp_interval_ms": _ms(intervals),
        "stamp_rate_hz": float(1.0 / np.median(intervals)) if intervals.size and np.median(intervals) > 0 else None,
        "stamps_out_of_order": out_of_order,
        "odometry_age_ms": None if lockstep else _ms(np.array([first_log[s] - s for s in counts]) * 1e-9),
        "commands": len(commands),
        "command_interval_ms": _ms(np.diff(command_times) * 1e-9),
        "first_response_ms": response,
    }


def timing_line(timing: dict[str, Any]) -> str:
    """One line of `odometry_timing`'s figures."""
    pattern = ", ".join(f"{n} with {k}" for k, n in timing["samples_per_stamp"].items())
    text = f"odometry {timing['odometry_messages']} messages, {timing['odometry_stamps']} stamps ({pattern} samples)"
    if timing["stamp_interval_ms"] is not None:
        i = timing["stamp_interval_ms"]
        text += f", stamp interval median {i['median']:.1f} ms, p99 {i['p99']:.1f} ms"
    if timing["odometry_age_ms"] is not None:
        text += f", age median {timing['odometry_age_ms']['median']:.1f} ms"
    text += f"; {timing['commands']} cmd_vel"
    if timing["first_response_ms"] is not None:
        text += f", first response {timing['first_response_ms']:.1f} ms"
    return text
