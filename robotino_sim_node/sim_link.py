"""The lockstep plant's emulated radio in sim time: packets in flight, handed out at the tick they are due.

As in the offline loop (`offline.networked`): a packet delivered at time d is handled at the first tick
t_k >= d (to `network.plan.TIME_TOLERANCE_S`); packets due at the same tick in the order of their delivery
times, then of their sending. Up-link ``seed + 1``, down-link ``seed + 2``.
"""

from __future__ import annotations

import heapq
import itertools
from typing import Any

from robotino_geom_mpc.network.link import Link, LinkParams
from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S

__all__ = ["SimLink", "SimQueue"]


class SimQueue:
    """One direction: `send` a packet at sim time t, `due` hands out those delivered by t."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self._heap: list[tuple[float, int, Any]] = []
        self._order = itertools.count()

    def send(self, now_s: float, packet: Any) -> int:
        """Put `packet` on the link at `now_s`; how many copies will arrive (0: lost)."""
        times = self.link.transmit(now_s)
        for delivery in times:
            heapq.heappush(self._heap, (delivery, next(self._order), packet))
        return len(times)

    def due(self, now_s: float) -> list[Any]:
        """The packets delivered by `now_s`, in order."""
        out = []
        while self._heap and self._heap[0][0] <= now_s + TIME_TOLERANCE_S:
            out.append(heapq.heappop(self._heap)[2])
        return out


class SimLink:
    """Both directions of a lockstep plant's link, and which delivered odometries the controller will answer.

    The controller answers an odometry only if its stamp is newer than every one it got before (an older one
    came reordered, a duplicate twice): `answers_due` counts those among the delivered stamps.
    """

    def __init__(self, up: LinkParams, down: LinkParams, seed: int) -> None:
        self.up = SimQueue(Link(up, seed + 1))
        self.down = SimQueue(Link(down, seed + 2))
        self.newest_ns: int | None = None

    def answers_due(self, stamps_ns: list[int]) -> int:
        """How many of the odometries delivered now (their stamps, in order) the controller answers."""
        count = 0
        for stamp in stamps_ns:
            if self.newest_ns is None or stamp > self.newest_ns:
                self.newest_ns = stamp
                count += 1
        return count
