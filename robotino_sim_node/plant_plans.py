"""The plant's packetized commands: plans in (`network.plan.PlanBuffer`), what it applied and when out.

With ``plans`` true the plant takes ``wheel_voltage_plan`` (``command_interface`` voltages) or ``cmd_vel_plan``
(cmd_vel) instead of the plain commands (`ros.plans` gives the messages). Each plan goes to a `PlanBuffer` at its
receipt time (the robot clock: sim time in lockstep, the node clock in realtime); a refused one (NaN, wrong
length, non-increasing times, a basis far in the future or the past) is logged (throttled) and counted
(``refused_plans``), older and duplicate ones only counted (``ignored_plans``), and the plans held stay. Per
control period the plant applies `PlanBuffer.command_at` at the period's start (zero volts / zero twist when
every plan is used up, as the watchdog gives them without plans; ``exhausted_periods``). ``command_applied``
reports each period's command (its start, the plan's basis, the entry) and each plan received, taken or not
(its receipt time: the controller's round trips);
the reports go out with the next odometry, over the same link.
"""

from __future__ import annotations

from typing import Any

from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectory

from robotino_geom_mpc.network.plan import AppliedCommand, PlanBuffer
from robotino_geom_mpc.ros.plans import IGNORED, PLAN_TOPICS, applied_message, offer_plan, plan_type
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["PlantPlans"]

ZERO = (0.0, 0.0, 0.0)


class PlantPlans:
    """The plan subscription's other half: the buffer, the refusals, the reports waiting for the next odometry.

    Parameters
    ----------
    node
        The plant node (its logger).
    interface
        ``voltages`` or ``cmd_vel``.
    period_s
        The control period (the length of a plan's last entry).
    """

    def __init__(self, node: Node, interface: str, period_s: float) -> None:
        self.node, self.interface, self.period_s = node, interface, period_s
        self.topic = PLAN_TOPICS[interface]
        self.msg_type = plan_type(interface)
        self.buffer = PlanBuffer()
        self.counts = {"refused_plans": 0, "ignored_plans": 0, "exhausted_periods": 0}
        self.reports: list[JointTrajectory] = []  # for the next up-link bundle, in order
        self.applied: tuple[float | None, int] | None = None  # (basis, index) of the last report
        self._period_start_s: float | None = None  # the control period being driven and its command
        self._period_values: tuple[float, ...] = ZERO

    def take(self, msg: Any, now_s: float) -> bool:
        """Offer a plan message received at robot time `now_s`; True when taken (its receipt is reported)."""
        reason, detail, _, receipt = offer_plan(self.buffer, msg, self.period_s, now_s, self.interface)
        if receipt is not None:
            self.reports.append(receipt)
        if reason in IGNORED:
            self.counts["ignored_plans"] += 1
            return False
        if reason is not None:
            self.counts["refused_plans"] += 1
            warn_throttled(self.node.get_logger(), f"refused {self.topic} ({reason}: {detail}); the plans held stay "
                f"({self.counts['refused_plans']} refused so far)", 1.0)
            return False
        return True

    def command_at(self, t_s: float, report: bool = True) -> tuple[AppliedCommand | None, tuple[float, ...]]:
        """The command of the period starting at `t_s` (None and zeros: no plan covers it); reported if `report`
        (and, without `report`, only when it differs from the last one reported).
        """
        applied = self.buffer.command_at(t_s)
        key = None if applied is None else (applied.basis_s, applied.entry_index)
        if applied is None and self.buffer.accepted:
            self.counts["exhausted_periods"] += 1
        if report or key != self.applied:
            self.applied = key
            values = ZERO if applied is None else applied.values
            self.reports.append(applied_message(t_s, key and key[0], -1 if key is None else key[1], values,
                                                self.interface))
        return applied, (ZERO if applied is None else applied.values)

    def period_command(self, start_s: float) -> tuple[float, ...]:
        """The command of the control period starting at `start_s`: chosen at its start (`command_at`) and held
        to its end, as the robot's command loop picks one entry per period (and `offline.networked` applies
        them): a plan taken within the period acts from the next one.
        """
        if start_s != self._period_start_s:
            self._period_start_s = start_s
            self._period_values = self.command_at(start_s, report=False)[1]
        return self._period_values

    def pop_reports(self) -> list[JointTrajectory]:
        """The reports since the last call, oldest first."""
        out, self.reports = self.reports, []
        return out
