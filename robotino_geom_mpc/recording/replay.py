"""Replay a bag over DDS with its original timing (scaled by a rate), optionally driving /clock.

Messages are republished serialized (the recorded CDR bytes), in log-time
order, each at ``start + (log_time - first_log_time) / rate`` on the steady
clock; each topic's publisher offers the recorded QoS (rosbag2's
adapt-offer rule: the recorded profile when all recorded publishers agree,
so the latched ``reference_path`` is offered transient local again).

With ``clock=True`` a rosgraph_msgs/Clock carrying the message's log time
is published on /clock just before every message whose log time is new
(a recorded /clock topic is then not replayed): use_sim_time consumers see
the recorded time advance in step with the data. Bags recorded with the
recorder's ``use_sim_time:=true`` carry the run's sim time as log time; the
default (receive time on the system clock) gives the wall time of the
recording, as ``ros2 bag play --clock`` does.

Timing jitter: each message is sent when a sleep until its due time returns
(Linux: typically < 0.2 ms late, a few ms on a loaded machine); the gaps
between messages are kept, not the absolute wall time of the recording.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.definitions import message_class

if TYPE_CHECKING:  # rclpy is imported by `replay_bag` only: reading a bag needs no ROS
    from rclpy.node import Node

__all__ = ["ReplayResult", "replay_bag"]


@dataclass
class ReplayResult:
    """What a replay did: messages published (per topic), passes over the bag, defects of the bag."""

    published: dict[str, int] = field(default_factory=dict)
    passes: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def total(self) -> int:
        return sum(self.published.values())


def _sleep_until(deadline: float) -> None:
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0.0:
            return
        time.sleep(min(remaining, 0.05))


def replay_bag(
    node: Node,
    bag: BagReader,
    *,
    rate: float = 1.0,
    loop: bool = False,
    topics: Iterable[str] | None = None,
    clock: bool = False,
    duration_s: float | None = None,
    delay_s: float = 1.0,
    wait_for_subscribers: bool = False,
    should_stop: Callable[[], bool] = lambda: False,
) -> ReplayResult:
    """Republish the messages of `bag` from `node` (which must not be spun elsewhere meanwhile).

    Parameters
    ----------
    node
        The node that owns the publishers.
    bag
        An open `BagReader` (its `problems` are copied into the result).
    rate
        Playback speed factor (> 0): 2 plays twice as fast.
    loop
        Start over at the end, until `duration_s` or `should_stop`.
    topics
        Only these topics (absolute names); None: all.
    clock
        Publish /clock from the recorded log times (see the module docstring).
    duration_s
        Stop after this much wall time of playback (None: at the end of the bag).
    delay_s
        Wait after creating the publishers, so subscribers discover them.
    wait_for_subscribers
        Before the delay, wait (at most 60 s) until every replayed topic (and
        /clock) has at least one matched subscription.

    Raises
    ------
    BagError
        If `rate` is not positive, a topic asked for is not in the bag, or a type is not installed.
    """
    from rclpy.duration import Duration
    from rosgraph_msgs.msg import Clock

    from robotino_geom_mpc.ros.bag_qos import adapt_offer_to_recorded

    if not rate > 0.0:
        raise BagError(f"rate must be > 0, got {rate!r}")
    if duration_s is not None and not duration_s > 0.0:
        raise BagError(f"duration must be > 0 s, got {duration_s!r}")
    wanted = set(bag.topics) if topics is None else set(topics)
    missing = sorted(wanted - set(bag.topics))
    if missing:
        raise BagError(f"topics not in the bag: {', '.join(missing)} (it has {', '.join(sorted(bag.topics))})")
    if clock:
        wanted.discard("/clock")
    publishers = {}
    for name in sorted(wanted):
        info = bag.topics[name]
        publishers[name] = node.create_publisher(
            message_class(info.type), name, adapt_offer_to_recorded(info.offered_qos_profiles, depth=100)
        )
    clock_pub = node.create_publisher(Clock, "/clock", 10) if clock else None
    messages = list(bag.messages(wanted))
    result = ReplayResult(published={name: 0 for name in publishers}, problems=list(bag.problems))
    if wait_for_subscribers:
        everyone = list(publishers.values()) + ([clock_pub] if clock_pub is not None else [])
        deadline = time.monotonic() + 60.0
        while any(p.get_subscription_count() < 1 for p in everyone) and time.monotonic() < deadline:
            if should_stop():
                return result
            time.sleep(0.01)
    time.sleep(max(delay_s, 0.0))
    if not messages:
        return result
    first = messages[0].log_time_ns
    start = time.monotonic()
    end = None if duration_s is None else start + duration_s
    while True:
        pass_start = time.monotonic()
        last_clock = None
        for msg in messages:
            due = pass_start + (msg.log_time_ns - first) * 1e-9 / rate
            if (end is not None and due > end) or should_stop():
                return result
            _sleep_until(due)
            if clock_pub is not None and msg.log_time_ns != last_clock:
                sec, nanosec = divmod(msg.log_time_ns, 1_000_000_000)
                stamp = Clock()
                stamp.clock.sec, stamp.clock.nanosec = sec, nanosec
                clock_pub.publish(stamp)
                last_clock = msg.log_time_ns
            publishers[msg.topic].publish(msg.data)
            result.published[msg.topic] += 1
        result.passes += 1
        if not loop:
            for pub in publishers.values():  # reliable subscribers get the last messages before the publishers go
                pub.wait_for_all_acked(Duration(seconds=2.0))
            return result
