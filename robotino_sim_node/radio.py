"""The realtime plant's emulated radio: each message leaves (or arrives) when the link delivers it.

A `Radio` holds one `loop.link_queue.LinkQueue` per direction (the link's one ordering, robot clock: the node's
clock in seconds). `Radio.send` queues the action (publish these bytes, or hand this command to the plant) for
each delivery of a message sent now (never, once or twice); a steady timer polls the queues every `POLL_S` and
runs what is due (within a poll of its time). A direction that
is off (`LinkParams.enabled` false) runs its actions at once. With both directions off and no plans the plant
does not create a radio: its messages go out as before.

Why a poll, not one timer re-armed to the earliest delivery: rclpy's events executor (Jazzy) loses timers that
are cancelled and reset a hundred times a second, including the plant's own tick timer (seen: the plant
"2 s behind: skipping ahead", half the odometries missing); a periodic timer is never reset.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from robotino_geom_mpc.loop.link_queue import LinkQueue
from robotino_geom_mpc.network.link import LinkParams
from robotino_geom_mpc.ros.spin import clock_s

__all__ = ["Radio"]

POLL_S = 0.001
"""How often the queue is polled [s]: a delivery runs within this of its time (the links' delays are 1-100 ms)."""


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
        self.queues: dict[str, LinkQueue[Callable[[], None]]] = {"up": LinkQueue(up, seed + 1),
                                                                  "down": LinkQueue(down, seed + 2)}
        self.timer = None  # both directions off (plans without a link): nothing is ever queued, nothing to poll
        if up.enabled or down.enabled:
            self.timer = node.create_timer(POLL_S, self._deliver, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def now_s(self) -> float:
        """The robot clock [s] (the node's clock)."""
        return clock_s(self.node)

    def send(self, way: str, action: Callable[[], None], now_s: float | None = None) -> int:
        """Queue `action` for each delivery of a message sent at `now_s` (default: now) on `way`; the count.

        On a direction that is off the action runs now (count 1).
        """
        queue = self.queues[way]
        if not queue.enabled:
            action()
            return 1
        return queue.send(self.now_s() if now_s is None else now_s, action)

    def _deliver(self) -> None:
        now_s = self.now_s()
        for queue in self.queues.values():
            for action in queue.due(now_s):
                action()
