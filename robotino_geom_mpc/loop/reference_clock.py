"""The trajectory node's timing as plain objects: when the reference's t = 0 is, which previews go out (no rclpy).

The trajectory node (`nodes.trajectory_node`, its docstring's Timing) reads the node clock, ``/clock``, the graph
and ``controller_enabled``, hands them here, and publishes what these objects answer:

* `RealtimeStart` (realtime): the reference starts (t = 0) at the first tick at which the start condition (a
  controller subscribed to the preview, a publisher of ``odom``, with ``anchor_to_robot`` the robot's pose) has held
  for the settle time, or with ``start_on_enable`` at the controller's enable after that (holding the start until
  then); a disable returns to the hold.
* `LockstepPreviews` (lockstep): on the clock of tick k the previews of tick k + 1, and of tick k itself on the first
  tick, a repeated clock or a jump, after those of the ticks skipped since the last one published (at most
  `GAP_FILL_TICKS`); the preview of tick t on the grid k Ts only.

Times are integers in ns (node clock, or the simulated time of ``/clock``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from enum import Enum

__all__ = ["GAP_FILL_TICKS", "LockstepPreviews", "RealtimeStart", "Tick", "path_stamps"]

GAP_FILL_TICKS = 100  # lockstep: the previews of at most this many skipped ticks are sent late


class Tick(Enum):
    """What a realtime timer tick does (`RealtimeStart.tick`)."""

    WAIT = "wait"  # the start condition has not held for the settle time: nothing is published
    HOLD = "hold"  # start_on_enable: the start point at rest until the controller's enable
    START = "start"  # t = 0 is now
    RUN = "run"  # the reference at `RealtimeStart.reference_ns`


class RealtimeStart:
    """Realtime: the start condition, the settle, the enable, the reference's t = 0 (module docstring).

    Parameters
    ----------
    settle_s
        How long the start condition must hold before the start [s] (``start_settle_s``).
    start_on_enable
        Hold the start until the controller's enable (``start_on_enable``).
    start_ns
        The reference's t = 0 if known already (lockstep: 0, the simulated time's origin), else None.
    """

    def __init__(self, settle_s: float, start_on_enable: bool, start_ns: int | None = None) -> None:
        self.settle_ns, self.start_on_enable = int(settle_s * 1e9), start_on_enable
        self.start_ns = start_ns  # the reference's t = 0 (node clock), None before the start
        self.ready_since_ns: int | None = None  # since when the start condition holds
        self.enabled = False  # the controller's controller_enabled

    def settled(self, now_ns: int, ready: Callable[[], bool]) -> bool:
        """Whether the start condition (`ready()`) has held for the settle time at `now_ns`; a lapse starts it over."""
        if not ready():
            self.ready_since_ns = None
            return False
        if self.ready_since_ns is None:
            self.ready_since_ns = now_ns
        return now_ns - self.ready_since_ns >= self.settle_ns

    def tick(self, now_ns: int, ready: Callable[[], bool]) -> Tick:
        """A timer tick at `now_ns` with the start condition `ready()`, asked only before the start (in the node a
        graph query: a fleet's trajectory process would ask it of every robot a tick).
        """
        if self.start_ns is not None:
            return Tick.RUN
        if not self.settled(now_ns, ready):
            return Tick.WAIT
        if self.start_on_enable and not self.enabled:
            return Tick.HOLD
        self.start_ns = now_ns
        return Tick.START

    def on_enabled(self, enabled: bool, now_ns: int, ready: Callable[[], bool]) -> Tick | None:
        """The controller's ``controller_enabled``: START at an enable once settled (t = 0 is the enable's arrival),
        HOLD at a disable after the start (the reference starts again at the next enable), None otherwise.
        """
        if enabled == self.enabled:
            return None
        self.enabled = enabled
        if enabled and self.start_ns is None and self.settled(now_ns, ready):
            self.start_ns = now_ns
            return Tick.START
        if not enabled and self.start_ns is not None:
            self.start_ns = None
            return Tick.HOLD
        return None

    def reference_ns(self, now_ns: int) -> int:
        """The reference's time at `now_ns` [ns] (0 before the start)."""
        return 0 if self.start_ns is None else now_ns - self.start_ns

    def reference_s(self, now_ns: int) -> float:
        """The reference's time at `now_ns` [s] (0 before the start)."""
        return self.reference_ns(now_ns) * 1e-9


class LockstepPreviews:
    """Lockstep: the ticks whose previews go out at each ``/clock`` (module docstring).

    Parameters
    ----------
    period_s
        The control period Ts [s].
    """

    def __init__(self, period_s: float) -> None:
        self.period_ns = int(round(period_s * 1e9))
        self.last_clock_ns: int | None = None  # the last /clock
        self.last_published_ns: int | None = None  # the stamp of the last preview published

    def on_clock(self, now_ns: int) -> list[int]:
        """The stamps to publish, in order, at the clock of tick `now_ns`."""
        current = now_ns == self.last_clock_ns or self.last_published_ns != now_ns
        self.last_clock_ns = now_ns
        return self._ahead(now_ns, current)

    def on_matched(self) -> list[int]:
        """A new preview subscription: the previews of the current tick (and the next) again; none before a clock."""
        return [] if self.last_clock_ns is None else self._ahead(self.last_clock_ns, True)

    def published(self, stamp_ns: int) -> None:
        """A preview stamped `stamp_ns` went out."""
        self.last_published_ns = stamp_ns

    def grid_index(self, t_ns: int) -> int | None:
        """k of t = k Ts (None off the grid or before 0)."""
        k, off = divmod(t_ns, self.period_ns)
        return None if off or k < 0 else k

    def reference_s(self) -> float:
        """The reference's time [s] a goal starts at: the latest tick published (0 before any)."""
        return (self.last_published_ns or 0) * 1e-9

    def last_clock_s(self) -> float | None:
        """The last tick's time [s], None before the first."""
        return None if self.last_clock_ns is None else self.last_clock_ns * 1e-9

    def _ahead(self, now_ns: int, current: bool) -> list[int]:
        """The preview of the tick after `now_ns`, after that of `now_ns` itself if `current`, and before it those
        of the ticks since the last one published (up to `GAP_FILL_TICKS`): a /clock the reader's history dropped in
        a burst of ticks (over a link the plant runs on at once through ticks with no answer due) would leave the
        preview of its next tick unsent, and an odometry of that stamp, delivered later, waiting.
        """
        stamps: list[int] = []
        period, last = self.period_ns, self.last_published_ns
        if current:
            if last is not None and now_ns - GAP_FILL_TICKS * period <= last < now_ns - period:
                stamps.extend(range(last + period, now_ns, period))
            stamps.append(now_ns)
        stamps.append(now_ns + period)
        return stamps


def path_stamps(start_ns: int, times_s: Iterable[float]) -> list[int]:
    """The stamps [ns] of the reference's poses at `times_s` [s] for a t = 0 at `start_ns`."""
    return [start_ns + int(round(t * 1e9)) for t in times_s]
