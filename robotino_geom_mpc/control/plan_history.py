"""What the robot applies, as an off-board controller knows it: the plans it sent and the robot's reports.

`PlanHistory` keeps the plans a `delay_compensation.DelayCompensatingController`
sent (with the accelerations u each entry meant and the drives' currents it
expected at the entry's end) and the robot's reports, all in the robot's clock:
per period what it applied (`report_applied`), per plan when it received it
and whether its buffer took it (`report_receipt`). `command` answers, for a
robot period, what ran or will run there: the reported command when there is
one, else the entry the robot's `network.plan.PlanBuffer` chooses among the
plans it holds: those received by then, and those in flight, taken to arrive
by their first entry (what the lead makes true for its quantile of the round
trips). A plan that was due at a reported period and did not run there (an
older plan, or none, ran) is taken as lost, until a receipt says it was late.

A report names a plan by its basis as the robot decoded it from the plan's
header (integer nanoseconds): at epoch times (1.8e9 s, a float's step 238 ns)
that is not always the float the controller computed, so a report's plan is the
one sent with a basis within `network.plan.TIME_TOLERANCE_S` of it (bases are a
period apart), never an exact float key.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S, CommandPlan

__all__ = ["ROUND_TRIP_WINDOW", "PlanHistory", "SentPlan"]

ROUND_TRIP_WINDOW = 200
"""Round trips the lead's quantile is taken over (the most recent ones: 2 s of plans at 100 Hz)."""


@dataclass
class SentPlan:
    """A plan as the controller sent it, with per entry the accelerations u it meant and the drives' currents
    expected at the entry's end, and what the reports say of its arrival.
    """

    plan: CommandPlan
    u: list[list[float]]
    end_currents: list[list[float]]
    received_s: float | None = None  # the robot's receipt time, once reported
    missed_by_s: float = -math.inf  # a reported period at or after its first entry ran without it (inf: refused)

    def arrived_by(self, t_s: float) -> bool:
        """Whether, as far as the reports say, the robot held this plan at its time t_s (in flight: on time)."""
        if self.received_s is not None:
            return self.received_s <= t_s + TIME_TOLERANCE_S
        return self.missed_by_s == -math.inf


class PlanHistory:
    """The plans sent and the robot's reports on them (robot clock).

    Parameters
    ----------
    period_s
        The control period Ts [s]; robot periods are counted from the first time seen.
    quantile
        The share of the round trips `round_trip_quantile` covers.
    memory_s
        Plans that ended, and reports, more than this before the newest plan are forgotten [s].

    Attributes
    ----------
    sent, received, lost, exhausted
        Plans sent; reported received; known not to have run when due (taken as lost); reported periods without
        a plan (after the first plan was sent).
    round_trips
        The last `ROUND_TRIP_WINDOW` round trips (receipt - basis) [s].
    """

    def __init__(self, period_s: float, quantile: float, memory_s: float) -> None:
        self.period_s, self.quantile, self.memory_s = float(period_s), float(quantile), float(memory_s)
        self._plans: dict[float, SentPlan] = {}  # by basis, in the order sent (increasing basis)
        self._bases: list[float] = []  # the keys of `_plans`, increasing (`_find`)
        self._applied: dict[int, tuple[float, int] | None] = {}  # period -> (basis, index), or None: no plan
        self._origin: float | None = None
        self.reported_s = -math.inf  # the latest period start reported on
        self.sent = self.received = self.lost = self.exhausted = self._samples = 0
        self.round_trips: deque[float] = deque(maxlen=ROUND_TRIP_WINDOW)
        self._quantile = (0, math.nan)  # (samples when computed, the quantile)

    def period(self, t_s: float) -> int:
        """The robot period starting at t_s, counted from the first time seen (the robot's periods' phase)."""
        if self._origin is None:
            self._origin = t_s
        return round((t_s - self._origin) / self.period_s)

    def add(self, plan: CommandPlan, u: list[list[float]], end_currents: list[list[float]]) -> None:
        """Keep a plan just sent (bases increase from plan to plan)."""
        self._plans[plan.basis_s] = SentPlan(plan, u, end_currents)
        self._bases.append(plan.basis_s)
        self.sent += 1
        if self.sent % 50 == 0:
            self._forget(plan.basis_s - self.memory_s)

    def _find(self, basis_s: float) -> SentPlan | None:
        """The plan sent with a basis within `TIME_TOLERANCE_S` of `basis_s` (a report's, decoded from ns)."""
        i = bisect.bisect_left(self._bases, basis_s - TIME_TOLERANCE_S)
        if i < len(self._bases) and self._bases[i] <= basis_s + TIME_TOLERANCE_S:
            return self._plans[self._bases[i]]
        return None

    def newest_first(self) -> list[SentPlan]:
        """The plans held, newest first (for `command`)."""
        return list(reversed(self._plans.values()))

    def report_receipt(self, basis_s: float, received_s: float, taken: bool = True) -> None:
        """The robot received the plan of basis `basis_s` at its time `received_s`; its buffer `taken` it or not.

        Every receipt is a round trip; a plan the buffer refused (older than one it runs) never runs.
        """
        sent = self._find(basis_s)
        self.round_trips.append(received_s - basis_s)
        self._samples += 1
        if sent is None or sent.received_s is not None:
            return
        if not taken:
            self.lost += sent.missed_by_s == -math.inf
            sent.missed_by_s = math.inf
            return
        self.received += 1
        self.lost -= sent.missed_by_s > -math.inf  # it was late, not lost
        sent.received_s = received_s

    def report_applied(self, time_s: float, basis_s: float | None, index: int = 0) -> None:
        """The robot applied entry `index` of plan `basis_s` from its time `time_s` (None: no plan, zero command)."""
        applied = None if basis_s is None else self._find(basis_s)
        if applied is not None:
            basis_s = applied.plan.basis_s  # the key the controller made it with
        self._applied[self.period(time_s)] = None if basis_s is None else (basis_s, index)
        self.reported_s = max(self.reported_s, time_s)
        self.exhausted += basis_s is None and bool(self._plans)
        for sent in reversed(self._plans.values()):  # a plan due by then that did not run was not there
            if basis_s is not None and sent.plan.basis_s <= basis_s + TIME_TOLERANCE_S:
                break  # held in the order sent: the rest are older
            if sent.received_s is None and sent.plan.times_s[0] <= time_s + TIME_TOLERANCE_S:
                self.lost += sent.missed_by_s == -math.inf
                sent.missed_by_s = max(sent.missed_by_s, time_s)

    def reported(self, period: int) -> bool:
        """Whether the robot has reported what it applied in `period`."""
        return period in self._applied

    def round_trip_quantile(self) -> float:
        """`quantile` of the recent round trips (nearest rank: the smallest value that covers that share of them),
        computed again only after new ones; NaN before any.
        """
        if not self.round_trips:
            return math.nan
        if self._quantile[0] != self._samples:
            trips = sorted(self.round_trips)
            rank = max(math.ceil(self.quantile * len(trips) - 1e-9), 1)
            self._quantile = (self._samples, trips[rank - 1])
        return self._quantile[1]

    def command(self, period: int, newest_first: list[SentPlan]
                ) -> tuple[list[float], list[float], tuple[float, float, float]] | None:
        """(u, end currents, entry) of what the robot applies in `period`: reported, else as its buffer chooses
        among `newest_first` (`newest_first()`); None for no plan (zero command).
        """
        if period in self._applied:
            applied = self._applied[period]
            if applied is None:
                return None
            basis, index = applied
            sent = self._plans.get(basis)
            if sent is None or index >= len(sent.u):
                return None
            return sent.u[index], sent.end_currents[index], sent.plan.entries[index]
        if self._origin is None:
            return None  # no period seen yet: no plan can be due
        t = self._origin + period * self.period_s
        for sent in newest_first:
            times = sent.plan.times_s
            if times[0] <= t + TIME_TOLERANCE_S and t < sent.plan.end_s - TIME_TOLERANCE_S and sent.arrived_by(t):
                index = round((t - times[0]) / self.period_s)
                return sent.u[index], sent.end_currents[index], sent.plan.entries[index]
        return None

    def _forget(self, before_s: float) -> None:
        """Drop the plans that ended, and the reports of periods, before `before_s`."""
        for basis in [b for b, s in self._plans.items() if s.plan.end_s < before_s]:
            del self._plans[basis]
        self._bases = list(self._plans)
        first = self.period(before_s)
        for period in [p for p in self._applied if p < first]:
            del self._applied[period]
