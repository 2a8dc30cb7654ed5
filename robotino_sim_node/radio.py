"""The realtime plant's emulated radio: each message leaves (or arrives) when the link delivers it.

A `Radio` holds one `network.link.Link` per direction and a queue of deliveries ordered by time (robot clock,
the node's clock in seconds). `Radio.send` asks the direction's link when a message sent now is delivered (never,
once or twice) and queues the action (publish these bytes, or hand this command to the plant) for each delivery;
one steady timer, re-armed to the earliest delivery, runs them when due. With both directions off the plant does
not create a radio: its messages go out as before.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from robotino_geom_mpc.network.link import Link, LinkParams

__all__ = ["Radio"]

_IDLE_NS = 3_600_000_000_000  # the timer's period while nothing is queued (it is re-armed on the next send)


class Radio:
    """The two directions of the link of a realtime node (`up`: the robot sends, `down`: the robot receives).

    Parameters
    ----------
    node
        The node (its clock is the robot's; its timers run the deliveries).
    up, down
        The directions' parameters.
    seed
        The run's seed: up uses `seed + 1`, down `seed + 2` (as `offline.networked`).
    """

    def __init__(self, node: Node, up: LinkParams, down: LinkParams, seed: int) -> None:
        self.node = node
        self.links = {"up": Link(up, seed + 1), "down": Link(down, seed + 2)}
        self.queue: list[tuple[float, int, Callable[[], None]]] = []
        self._order = itertools.count()
        self.timer = node.create_timer(_IDLE_NS * 1e-9, self._deliver, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def now_s(self) -> float:
        """The robot clock [s] (the node's clock)."""
        return self.node.get_clock().now().nanoseconds * 1e-9

    def send(self, way: str, action: Callable[[], None], now_s: float | None = None) -> int:
        """Queue `action` for each delivery of a message sent at `now_s` (default: now) on `way`; the count."""
        now_s = self.now_s() if now_s is None else now_s
        times = self.links[way].transmit(now_s)
        for t in times:
            heapq.heappush(self.queue, (t, next(self._order), action))
        self._arm(now_s)
        return len(times)

    def _arm(self, now_s: float) -> None:
        period_ns = _IDLE_NS if not self.queue else max(1, int((self.queue[0][0] - now_s) * 1e9))
        self.timer.cancel()  # (the events executor takes a new period only from a cancelled timer)
        self.timer.timer_period_ns = period_ns
        self.timer.reset()

    def _deliver(self) -> None:
        now_s = self.now_s()
        while self.queue and self.queue[0][0] <= now_s:
            heapq.heappop(self.queue)[2]()
        self._arm(now_s)
