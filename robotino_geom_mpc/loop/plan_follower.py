"""The robot's side of packetized commands: plans taken into a `network.plan.PlanBuffer`, one entry per period, reports.

One implementation for the plant (simulated robot, `loop.robot_loop.RobotLoop`) and the command buffer node (a
real robot's PC): a plan offered at robot time t is taken or refused (`PlanBuffer.offer`: a malformed one, one far
in the future or the past; older and duplicate ones are no fault, `IGNORED`), and reported as received; per control
period the entry the plans held at the period's start give is applied (zero when every plan is used up) and
reported as applied. The reports (`PlanReport`) wait for the robot's next up-link packet (`pop_reports`); the
adapters turn them into ``command_applied`` messages (`ros.plans`), the offline loop hands them to the controller.
"""

from __future__ import annotations

from typing import NamedTuple

from robotino_geom_mpc.network.plan import AppliedCommand, CommandPlan, PlanBuffer

__all__ = ["IGNORED", "PlanFollower", "PlanReport", "ZERO"]

ZERO = (0.0, 0.0, 0.0)
IGNORED = ("older", "duplicate")
"""`PlanBuffer.offer`'s refusals that are no fault (reordering and duplicates on a link): counted, not logged."""


class PlanReport(NamedTuple):
    """One ``command_applied`` event: `values` None = receipt of plan `basis_s` at `time_s` (`taken` by the buffer or
    not); else the period starting at `time_s` got `values` (entry `entry_index` of plan `basis_s`; basis None: no
    plan, zero, index -1).
    """

    time_s: float
    basis_s: float | None
    entry_index: int
    values: tuple[float, float, float] | None
    taken: bool = True


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
        self.reports: list[PlanReport] = []  # for the next up-link packet, in order
        self._reported: tuple[float | None, int] | None = None  # (basis, index) of the last applied report
        self._period_start_s: float | None = None  # the control period being driven and its command
        self._period_values: tuple[float, float, float] = ZERO

    def take(self, plan: CommandPlan, now_s: float) -> str | None:
        """Offer `plan` received at robot time `now_s` (its receipt reported); None when taken, else the reason."""
        reason = self.buffer.offer(plan, now_s)
        self.reports.append(PlanReport(now_s, plan.basis_s, -1, None, reason is None))
        if reason in IGNORED:
            self.counts["ignored_plans"] += 1
        elif reason is not None:
            self.counts["refused_plans"] += 1
        return reason

    def refuse(self, reason: str) -> None:
        """Count a plan that could not be read at all (`ros.plans.PlanMessageError`'s reason): nothing to report."""
        self.counts["ignored_plans" if reason in IGNORED else "refused_plans"] += 1

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
            self.reports.append(PlanReport(t_s, None if key is None else key[0], -1 if key is None else key[1],
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

    def pop_reports(self) -> list[PlanReport]:
        """The reports since the last call, oldest first."""
        out, self.reports = self.reports, []
        return out
