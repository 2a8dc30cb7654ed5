"""The radio link a recording shows: what the controller received and when, what the robot reported applying.

Everything the plant publishes crosses the link before the recorder (and the controller) gets it; the plans are
recorded as the controller sends them, before the down-link; the robot's ``command_applied`` reports come back
over the up-link. From these alone (`link_figures`):

* ``odometry_received`` / ``odometry_expected`` and ``up_loss``: distinct ``odom`` stamps recorded against the
  stamps from the first to the last (one a control period): the up-link's loss as the controller saw it;
* ``odometry_age_ms`` (median, p99, max): receive time (the recorder's log time) - stamp, for a realtime run
  whose recorder shares the robot's clock (one host, or synchronised hosts; None in lockstep, where stamps are
  sim time): the up-link's delay plus the transport's;
* ``round_trip_ms`` (mean, std, p99, from the reports): the robot's receipt of a plan - its basis, the robot's
  clock alone: up-link, controller and down-link;
* ``plans_sent`` (recorded), ``plans_received`` (receipts reported), ``down_loss`` 1 - received / sent (the
  receipts ride the up-link: its losses hide some, so this bounds the down-link's loss from above, about
  ``up_loss`` too high), ``periods_without_plan`` (periods reported with no plan after the first plan).

None of them without plans in the recording (``link_figures`` returns None).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.topics import by_publish_time, find_topic, plan_topic, stamp_ns
from robotino_geom_mpc.ros.plans import PlanMessageError, report_of_message

__all__ = ["link_figures", "link_line"]


def _ms(values: list[float], *stats: str) -> dict[str, float] | None:
    if not values:
        return None
    a = 1e3 * np.array(values)
    table: dict[str, Callable[[], Any]] = {"mean": a.mean, "std": a.std, "median": lambda: np.median(a),
                                           "p99": lambda: np.percentile(a, 99), "max": a.max}
    return {name: float(table[name]()) for name in stats}


def link_figures(bag: BagReader, period_s: float, lockstep: bool) -> dict[str, Any] | None:
    """The link's figures of a recording with plans (the module docstring), None without plans."""
    found = plan_topic(bag)
    if found is None:
        return None
    odom_topic = find_topic(bag, "odom", "nav_msgs/msg/Odometry", False)
    first_seen: dict[int, int] = {}
    for m in bag.messages([odom_topic] if odom_topic else []):
        stamp = _odom_stamp_ns(m.data)
        first_seen.setdefault(stamp, m.log_time_ns)
    stamps = sorted(first_seen)
    expected = round((stamps[-1] - stamps[0]) * 1e-9 / period_s) + 1 if stamps else 0
    trips, received, without = [], set(), 0
    any_plan = False
    for _, msg in by_publish_time(bag, find_topic(bag, "command_applied", "trajectory_msgs/msg/JointTrajectory",
                                                  False)):
        try:
            report = report_of_message(msg)
        except PlanMessageError:
            continue
        if report.basis_s is None:  # a period applied without a plan (a receipt always names its plan)
            without += 1 if any_plan else 0
        elif report.values is None:  # a receipt
            trips.append(report.time_s - report.basis_s)
            received.add(report.basis_s)
        else:
            any_plan = True
    sent = len({stamp_ns(msg.header.stamp) for _, msg in by_publish_time(bag, found[0])})
    return {
        "odometry_received": len(stamps), "odometry_expected": expected,
        "up_loss": 1.0 - len(stamps) / expected if expected else None,
        "odometry_age_ms": None if lockstep else _ms([(t - s) * 1e-9 for s, t in first_seen.items()],
                                                     "median", "p99", "max"),
        "round_trip_ms": _ms(trips, "mean", "std", "p99"),
        "plans_sent": sent, "plans_received": len(received),
        "down_loss": 1.0 - len(received) / sent if sent else None,
        "periods_without_plan": without,
    }


def _odom_stamp_ns(data: bytes) -> int:
    """The header stamp [ns] of a serialized odometry (CDR: 4 bytes of encapsulation, then sec, nanosec)."""
    sec, nanosec = np.frombuffer(data, dtype="<u4", count=2, offset=4).tolist()
    return sec * 1_000_000_000 + nanosec


def link_line(figures: dict[str, Any]) -> str:
    """One line of a run's link figures."""
    trip = figures["round_trip_ms"]
    age = figures["odometry_age_ms"]
    text = (f"odometry {figures['odometry_received']}/{figures['odometry_expected']} received "
            f"(up loss {100 * (figures['up_loss'] or 0.0):.1f} %)")
    if age is not None:
        text += f", age median {age['median']:.1f} ms, p99 {age['p99']:.1f} ms"
    if trip is not None:
        text += f"; round trip {trip['mean']:.1f} ms mean, {trip['std']:.1f} ms std, p99 {trip['p99']:.1f} ms"
    return text + (f"; plans {figures['plans_received']}/{figures['plans_sent']} reported received "
                   f"(down loss <= {100 * (figures['down_loss'] or 0.0):.1f} %), "
                   f"{figures['periods_without_plan']} periods without a plan")
