"""One direction of the emulated radio link on the robot's clock: packets in flight, handed out when due.

The one place where the link's ordering is written (the offline loop, the lockstep plant and the realtime
plant's radio all queue their packets here): `LinkQueue.send` asks the direction's `network.link.Link` when a
packet sent now is delivered (never, once, twice) and keeps each delivery; `LinkQueue.due` hands out those
delivered by a time, to `network.plan.TIME_TOLERANCE_S` (a loop that advances in whole periods handles a
packet delivered at d at the first tick t_k >= d), in the order of their delivery times, then of their
sending. Up-link ``seed + 1``, down-link ``seed + 2`` (`RobotLink`).
"""

from __future__ import annotations

import heapq
import itertools
from typing import Any, Generic, TypeVar

from robotino_geom_mpc.network.link import Link, LinkParams
from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S

__all__ = ["LinkQueue", "RobotLink"]

P = TypeVar("P")


class LinkQueue(Generic[P]):
    """One direction: `send` a packet at robot time t [s], `due` hands out those delivered by a time.

    Parameters
    ----------
    params
        The direction's parameters (None: a perfect link, every packet delivered once, at once).
    seed
        Seed of the direction's generator.
    """

    def __init__(self, params: LinkParams | None, seed: int) -> None:
        self.link = Link(params or LinkParams(), seed)
        self._heap: list[tuple[float, int, P]] = []
        self._order = itertools.count()

    @property
    def enabled(self) -> bool:
        """True when the direction delays, loses or duplicates anything."""
        return self.link.params.enabled

    def send(self, now_s: float, packet: P) -> int:
        """Put `packet` on the link at `now_s`; how many copies will arrive (0: lost)."""
        times = self.link.transmit(now_s)
        for delivery in times:
            heapq.heappush(self._heap, (delivery, next(self._order), packet))
        return len(times)

    def due(self, now_s: float) -> list[P]:
        """The packets delivered by `now_s`, in order (delivery time, then sending)."""
        out = []
        while self._heap and self._heap[0][0] <= now_s + TIME_TOLERANCE_S:
            out.append(heapq.heappop(self._heap)[2])
        return out


class RobotLink:
    """Both directions of a robot's link (`up`: the robot sends, `down`: it receives), seeded as one run.

    In lockstep the robot also knows how many of the odometries it delivered the controller answers: one
    whose stamp is newer than every one delivered before (an older one came reordered, a duplicate twice),
    `answers_due`.
    """

    def __init__(self, up: LinkParams | None, down: LinkParams | None, seed: int) -> None:
        self.up: LinkQueue[Any] = LinkQueue(up, seed + 1)
        self.down: LinkQueue[Any] = LinkQueue(down, seed + 2)
        self.newest_ns: int | None = None

    def answers_due(self, stamps_ns: list[int]) -> int:
        """How many of the odometries delivered now (their stamps [ns], in order) the controller answers."""
        count = 0
        for stamp in stamps_ns:
            if self.newest_ns is None or stamp > self.newest_ns:
                self.newest_ns = stamp
                count += 1
        return count
