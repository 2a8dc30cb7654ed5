"""The robot's side of packetized commands: plans taken into a `network.plan.PlanBuffer`, one entry per period, reports.

One implementation for the plant (simulated robot, `loop.robot_loop.RobotLoop`) and the command buffer node (a
real robot's PC): a plan offered at robot time t is taken or refused (`PlanBuffer.offer`: a malformed one, one far
in the future or the past; older and duplicate ones are no fault, `IGNORED`), and reported as received; per control
period the entry the plans held at the period's start give is applied (zero when every plan is used up) and
reported as applied. The reports (`loop.events.AppliedReport`) wait for the robot's next up-link packet
(`pop_reports`); the adapters turn them into ``command_applied`` messages (`ros.plans`), the offline loop hands
them to the controller.

`PlanDispatcher` is the command buffer's side (a real robot's PC, polled on its clock): each period's entry goes
out once at its start and holds to its end; every plan used up, a zero command once a period for a while, then
nothing until the next plan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from robotino_geom_mpc.loop.events import AppliedReport
from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S, AppliedCommand, CommandPlan, PlanBuffer

__all__ = ["IGNORED", "PlanDispatcher", "PlanFollower", "Unreadable", "ZERO"]

ZERO = (0.0, 0.0, 0.0)
IGNORED = ("older", "duplicate")
"""`PlanBuffer.offer`'s refusals that are no fault (reordering and duplicates on a link): counted, not logged."""


@dataclass(frozen=True)
class Unreadable:
    """A plan message that could not be read (`ros.plans.PlanMessageError`: its reason and message)."""

    reason: str
    detail: str


class PlanFollower:
    """The plan buffer, the period's command and the reports (module docstring).

    Parameters
    ----------
    period_s
        The control period [s] (a plan's last entry lasts this long; periods start at its multiples).
    buffer
        The buffer (a fresh `PlanBuffer` if None).
    """

    def __init__(self, period_s: float, buffer: PlanBuffer | None = None) -> None:
        self.period_s = period_s
        self.buffer = PlanBuffer() if buffer is None else buffer
        self.counts = {"refused_plans": 0, "ignored_plans": 0, "exhausted_periods": 0}
        self.refused: dict[str, int] = {}  # the refused plans per reason (not the ignored ones)
        self.reports: list[AppliedReport] = []  # for the next up-link packet, in order
        self._reported: tuple[float | None, int] | None = None  # (basis, index) of the last applied report
        self._period_start_s: float | None = None  # the control period being driven and its command
        self._period_values: tuple[float, float, float] = ZERO

    def take(self, plan: CommandPlan | Unreadable, now_s: float) -> str | None:
        """Offer `plan` received at robot time `now_s` (its receipt reported); None when taken, else the reason
        (an unreadable one: its reason, counted, nothing reported).
        """
        if isinstance(plan, Unreadable):
            self.refuse(plan.reason)
            return plan.reason
        reason = self.buffer.offer(plan, now_s)
        self.reports.append(AppliedReport(now_s, plan.basis_s, -1, None, reason is None))
        if reason is not None:
            self.refuse(reason)
        return reason

    def refuse(self, reason: str) -> None:
        """Count a refused plan (also one that could not be read at all, `ros.plans.PlanMessageError`'s reason)."""
        if reason in IGNORED:
            self.counts["ignored_plans"] += 1
            return
        self.counts["refused_plans"] += 1
        self.refused[reason] = self.refused.get(reason, 0) + 1

    def command_at(self, t_s: float, report: bool = True) -> tuple[AppliedCommand | None, tuple[float, float, float]]:
        """The command of the period starting at `t_s` (None and zeros: no plan covers it); reported if `report`
        (and, without `report`, only when it differs from the last one reported).
        """
        applied = self.buffer.command_at(t_s)
        key = None if applied is None else (applied.basis_s, applied.entry_index)
        if applied is None and self.buffer.accepted:
            self.counts["exhausted_periods"] += 1
        values = ZERO if applied is None else applied.values
        if report or key != self._reported:
            self._reported = key
            self.reports.append(AppliedReport(t_s, None if key is None else key[0], -1 if key is None else key[1],
                                           values))
        return applied, values

    def period_command(self, start_s: float) -> tuple[float, float, float]:
        """The command of the control period starting at `start_s`: chosen at its start (`command_at`) and held to
        its end, as the robot's command loop picks one entry per period: a plan taken within the period acts from
        the next one.
        """
        if start_s != self._period_start_s:
            self._period_start_s = start_s
            self._period_values = self.command_at(start_s, report=False)[1]
        return self._period_values

    def pop_reports(self) -> list[AppliedReport]:
        """The reports since the last call, oldest first."""
        out, self.reports = self.reports, []
        return out


class PlanDispatcher:
    """The command buffer's tick on the robot's clock (times handed in, seconds): what goes out to the driver when.

    Parameters
    ----------
    follower
        The plans and their reports.
    idle_after_s
        With every plan used up, a zero command goes out once a period for this long; then nothing until the next
        plan [s].

    Attributes
    ----------
    active
        A plan was taken and the idle time has not run out.
    round_trip_s
        The last plan's receipt time minus its basis: its one-way delay plus the odometry's age at the controller.
    """

    def __init__(self, follower: PlanFollower, idle_after_s: float) -> None:
        self.follower, self.idle_after_s = follower, idle_after_s
        self.active = False
        self.round_trip_s = math.nan
        self._period_end_s = -math.inf  # when the entry sent last stops running
        self._next_zero_s = -math.inf  # every plan used up: when the next zero goes out
        self._exhausted_since: float | None = None

    def take(self, plan: CommandPlan, now_s: float) -> str | None:
        """`PlanFollower.take`; a plan taken makes the next poll send what runs now (zero before its first entry)."""
        reason = self.follower.take(plan, now_s)
        if reason is None:
            self.round_trip_s = now_s - plan.basis_s
            self.active = True
        return reason

    def poll(self, now_s: float) -> tuple[float, float, float] | None:
        """The command to send now (its report queued in the follower), None: nothing. A plan taken within a
        period acts from the next one (as `PlanFollower.period_command`); after `idle_after_s` with every plan
        used up the dispatcher goes idle (`active` false).
        """
        if not self.active or now_s < self._period_end_s - TIME_TOLERANCE_S:  # idle, or the entry sent last runs
            return None
        follower = self.follower
        applied = follower.buffer.command_at(now_s)
        if applied is None:
            start = now_s if self._exhausted_since is None else self._exhausted_since
            self._exhausted_since, self._period_end_s = start, -math.inf  # a plan may start at any poll
            if now_s - start >= self.idle_after_s:
                self.active = False
            elif now_s >= self._next_zero_s:
                follower.counts["exhausted_periods"] += 1
                self._next_zero_s = now_s + follower.period_s
                follower.reports.append(AppliedReport(now_s, None, -1, ZERO))
                return ZERO
            return None
        self._exhausted_since, self._next_zero_s = None, -math.inf
        begin, self._period_end_s = follower.buffer.entry_span(applied, follower.period_s)
        follower.reports.append(AppliedReport(begin, applied.basis_s, applied.entry_index, applied.values))
        return applied.values
