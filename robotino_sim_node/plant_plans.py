"""The plant's packetized commands on ROS: plan messages into `loop.plan_follower.PlanFollower`, its reports out.

With ``plans`` true the plant takes ``wheel_voltage_plan`` (``command_interface`` voltages) or ``cmd_vel_plan``
(cmd_vel) instead of the plain commands (`ros.plans` gives the messages). Each plan message is read and handed to
the follower at its receipt time (the robot clock: sim time in lockstep, the node clock in realtime); a refused one
(NaN, wrong length, non-increasing times, a basis far in the future or the past) is logged (throttled) and counted
(``refused_plans``), older and duplicate ones only counted (``ignored_plans``), and the plans held stay. The
follower chooses each period's command (`PlanFollower.command_at`, `PlanFollower.period_command`: zero volts /
zero twist when every plan is used up, ``exhausted_periods``); its reports (each period's command, each plan
received, taken or not) go out on ``command_applied`` with the next odometry, over the same link.
"""

from __future__ import annotations

from typing import Any

from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectory

from robotino_geom_mpc.loop.plan_follower import IGNORED, PlanFollower
from robotino_geom_mpc.ros.plans import PLAN_TOPICS, PlanMessageError, applied_message, plan_of_message, plan_type, \
    received_message
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["PlantPlans"]


class PlantPlans:
    """The plan subscription's other half: messages to the follower, refusals logged, reports to messages.

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
        self.follower = PlanFollower(period_s)
        self.counts = self.follower.counts

    def take(self, msg: Any, now_s: float) -> bool:
        """Offer a plan message received at robot time `now_s`; True when taken (its receipt is reported)."""
        reason: str | None
        try:
            plan = plan_of_message(msg, self.period_s)
        except PlanMessageError as exc:
            reason, detail = exc.reason, str(exc)
            self.follower.refuse(reason)
        else:
            reason, detail = self.follower.take(plan, now_s), f"basis {plan.basis_s:.6f} s, {len(plan.times_s)} entries"
        if reason is not None and reason not in IGNORED:
            warn_throttled(self.node.get_logger(), f"refused {self.topic} ({reason}: {detail}); the plans held stay "
                           f"({self.counts['refused_plans']} refused so far)", 1.0)
        return reason is None

    def command_at(self, t_s: float) -> tuple[float, float, float]:
        """The command of the period starting at `t_s`, reported (`PlanFollower.command_at`)."""
        return self.follower.command_at(t_s)[1]

    def period_command(self, start_s: float) -> tuple[float, float, float]:
        """`PlanFollower.period_command`: the command the plans held at the period's start gave."""
        return self.follower.period_command(start_s)

    def pop_reports(self) -> list[JointTrajectory]:
        """The reports since the last call as ``command_applied`` messages, oldest first."""
        return [applied_message(r.time_s, r.basis_s, r.entry_index, r.values, self.interface) if r.basis_s is None
                or r.values is not None else received_message(r.time_s, r.basis_s, self.interface, r.taken)
                for r in self.follower.pop_reports()]
