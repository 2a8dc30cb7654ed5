"""Packetized commands: a plan of timed entries, and the robot-side buffer that applies the newest one.

Every command the off-board controller sends is a `CommandPlan`: the
commands (wheel voltages [V], or body twists (v_x, v_y, theta') in
base_link with the cmd_vel interface) for the next M periods, each with the
robot time at which it starts to apply. The robot keeps them in a
`PlanBuffer` and, once per control period at its own time t, applies the
entry of the period containing t from the newest plan (largest basis) that
covers t. A late or lost plan is so covered by the previous one; a
duplicate, or a plan older than one already running (which could never be
chosen), is ignored; when no plan covers t any more the
robot gets no command (`PlanBuffer.command_at` returns None): zero volts or
zero twist, as the watchdog gives without plans.

All times are the robot's clock (see docs/howto/networked_control.md):
a plan's basis is the stamp of the odometry it was computed from, its entry
times are that stamp plus whole periods. Entry boundaries are compared with
a tolerance of `TIME_TOLERANCE_S`, so a period start and an entry time that
differ by rounding (a sum of periods in floating point, or a stamp through
integer nanoseconds) are the same instant.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import NamedTuple

from robotino_geom_mpc.arrays import float_triple
from robotino_geom_mpc.errors import RobotinoError

__all__ = ["AppliedCommand", "CommandPlan", "PlanBuffer", "PlanError", "REFUSALS", "TIME_TOLERANCE_S"]

TIME_TOLERANCE_S = 1e-6
"""Two robot times closer than this are one instant (entry starts against period starts)."""

REFUSALS = ("nan", "length", "times", "future", "past", "older", "duplicate")
"""Why `PlanBuffer.offer` refuses a plan; the last two are normal on a link (reordering, duplicates), not errors."""


class PlanError(RobotinoError, ValueError):
    """A bad buffer setting, named in the message."""


@dataclass(frozen=True)
class CommandPlan:
    """The commands of the next periods, each with the robot time at which it starts to apply.

    Attributes
    ----------
    basis_s
        Stamp of the odometry the plan was computed from (robot clock) [s].
    times_s
        Absolute robot times at which entry i starts to apply, strictly increasing [s].
    entries
        Per entry the three wheel voltages [V] or the body twist (v_x [m/s], v_y [m/s], theta' [rad/s]).
    period_s
        The last entry applies for [times_s[-1], times_s[-1] + period_s) [s].

    A plan is built as it comes (from a message, possibly corrupt); `PlanBuffer.offer` checks it.
    """

    basis_s: float
    times_s: tuple[float, ...]
    entries: tuple[tuple[float, float, float], ...]
    period_s: float

    @property
    def end_s(self) -> float:
        """The end of the last entry's period [s]."""
        return self.times_s[-1] + self.period_s

    def problem(self) -> str | None:
        """Why the plan is malformed (``nan``, ``length`` or ``times``), or None."""
        try:
            values = [float(self.basis_s), float(self.period_s), *map(float, self.times_s)]
            if len(self.entries) != len(self.times_s) or not self.entries or any(len(e) != 3 for e in self.entries):
                return "length"
            values += [float(v) for e in self.entries for v in e]
        except (TypeError, ValueError):
            return "length"
        if not all(map(math.isfinite, values)):
            return "nan"
        times = self.times_s
        if not (self.period_s > 0.0 and times[0] >= self.basis_s - TIME_TOLERANCE_S
                and all(b > a for a, b in zip(times, times[1:]))):
            return "times"
        return None


class AppliedCommand(NamedTuple):
    """What the robot applies from `time_s` on: entry `entry_index` of the plan of basis `basis_s`.

    Attributes
    ----------
    time_s
        The robot time of the query: the start of the period it is applied for [s].
    basis_s
        The basis of the plan it comes from [s].
    entry_index
        The entry's index in that plan.
    values
        The entry: three voltages [V] or a body twist.
    """

    time_s: float
    basis_s: float
    entry_index: int
    values: tuple[float, float, float]


class PlanBuffer:
    """The robot side of packetized commands: holds the plans received, applies the newest's entry.

    Parameters
    ----------
    max_future_s
        A plan whose basis is more than this ahead of the robot's time is refused (``future``) [s].
    max_age_s
        A plan whose basis is more than this behind the robot's time is refused (``past``) [s].
    max_plans
        Plans held at most. A plan is dropped once used up or outlasted by a newer plan that has started;
        beyond this many (plans sent far ahead of their first entry), the oldest go first.

    Attributes
    ----------
    accepted
        Plans taken.
    refused
        Per reason of `REFUSALS`, the plans refused.
    exhausted
        `command_at` calls that found no plan covering their time although a plan had been taken.
    """

    def __init__(self, max_future_s: float = 0.5, max_age_s: float = 1.0, max_plans: int = 256) -> None:
        for name, value in (("max_future_s", max_future_s), ("max_age_s", max_age_s)):
            if not (math.isfinite(value) and value > 0.0):
                raise PlanError(f"{name} must be a positive number of seconds, got {value!r}")
        if max_plans < 1:
            raise PlanError(f"max_plans must be >= 1, got {max_plans!r}")
        self.max_future_s, self.max_age_s, self.max_plans = float(max_future_s), float(max_age_s), int(max_plans)
        self.reset()

    def reset(self) -> None:
        """Forget every plan and counter."""
        self._plans: list[CommandPlan] = []  # oldest basis first
        self._newest = -math.inf
        self.accepted = self.exhausted = 0
        self.refused = dict.fromkeys(REFUSALS, 0)

    @property
    def plans(self) -> tuple[CommandPlan, ...]:
        """The plans held, oldest basis first."""
        return tuple(self._plans)

    def offer(self, plan: CommandPlan, now_s: float) -> str | None:
        """Take `plan` received at robot time `now_s`; None when taken, else the reason of `REFUSALS`.

        A plan older than the newest held is taken only while it can still be chosen: a plan overtaken on
        the link by a newer one that has not started yet still covers the periods before that one's first
        entry (what the controller assumed when it sent the newer one). It is refused as ``older`` once a
        newer plan that has started outlasts it, and as ``duplicate`` when a plan of its basis is held or
        was the newest taken. A refused plan changes nothing but its counter; the plans held stay.
        """
        reason = plan.problem()
        if reason is None:
            if plan.basis_s > now_s + self.max_future_s:
                reason = "future"
            elif plan.basis_s < now_s - self.max_age_s:
                reason = "past"
            elif plan.basis_s == self._newest or any(p.basis_s == plan.basis_s for p in self._plans):
                reason = "duplicate"
            elif plan.basis_s < self._newest and plan not in self._useful(now_s, plan):
                reason = "older"
        if reason is not None:
            self.refused[reason] += 1
            return reason
        self._newest = max(self._newest, plan.basis_s)
        useful = self._useful(now_s, plan)
        self._plans = useful[max(len(useful) - self.max_plans, 0):]
        self.accepted += 1
        return None

    def _useful(self, now_s: float, extra: CommandPlan | None = None) -> list[CommandPlan]:
        """The plans held (and `extra`), oldest basis first, that a time from `now_s` on can still choose: not
        used up, not outlasted by a newer plan that has started.
        """
        plans = sorted(self._plans + ([extra] if extra is not None else []), key=lambda p: p.basis_s)
        out, started_end = [], -math.inf  # the latest end among the newer plans already started
        for plan in reversed(plans):
            if plan.end_s > now_s + TIME_TOLERANCE_S and plan.end_s > started_end + TIME_TOLERANCE_S:
                out.append(plan)
            if plan.times_s[0] <= now_s + TIME_TOLERANCE_S:
                started_end = max(started_end, plan.end_s)
        return out[::-1]

    def command_at(self, t_s: float) -> AppliedCommand | None:
        """The entry of the period containing `t_s` from the newest plan that covers it; None if none does."""
        for plan in reversed(self._plans):
            times = plan.times_s
            if times[0] <= t_s + TIME_TOLERANCE_S and t_s < plan.end_s - TIME_TOLERANCE_S:
                index = bisect.bisect_right(times, t_s + TIME_TOLERANCE_S) - 1
                return AppliedCommand(t_s, plan.basis_s, index, float_triple(plan.entries[index]))
        if self.accepted:
            self.exhausted += 1
        return None

    def entry_span(self, applied: AppliedCommand, period_s: float) -> tuple[float, float]:
        """When `applied`'s entry starts and stops applying unless a newer plan arrives: its start in its plan and
        the next entry's start, or the plan's end; from `applied.time_s` for `period_s` if its plan is no longer held.
        """
        for plan in self._plans:
            if plan.basis_s == applied.basis_s:
                following = applied.entry_index + 1
                end = plan.times_s[following] if following < len(plan.times_s) else plan.end_s
                return plan.times_s[applied.entry_index], end
        return applied.time_s, applied.time_s + period_s

