"""The plant's packetized commands on ROS: plan messages read for `loop.plan_follower.PlanFollower`, its reports out.

With ``plans`` true the plant takes ``wheel_voltage_plan`` (``command_interface`` voltages) or ``cmd_vel_plan``
(cmd_vel) instead of the plain commands (`ros.plans` gives the messages). Each message is read (`read`: a
`network.plan.CommandPlan`, or `Unreadable`) and offered to the follower at its receipt time (the robot clock:
sim time in lockstep, the node clock in realtime); a refused one (NaN, wrong length, non-increasing times, a
basis far in the future or the past) is logged (throttled) and counted (``refused_plans``), older and duplicate
ones only counted (``ignored_plans``), and the plans held stay. The follower's reports (each period's command,
each plan received, taken or not) go out on ``command_applied`` with the next odometry, over the same link.
"""

from __future__ import annotations

from typing import Any

from robotino_geom_mpc.loop.events import AppliedReport, Level, Log
from robotino_geom_mpc.loop.plan_follower import IGNORED, PlanFollower, Unreadable
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.ros.plans import PLAN_TOPICS, PlanMessageError, applied_message, plan_of_message, plan_type, \
    received_message
from robotino_sim_node.outputs import Message, PlantOutputs

__all__ = ["PlantPlans"]


class PlantPlans:
    """The plan subscription's other half: messages read, refusals logged, reports to messages.

    Parameters
    ----------
    outputs
        The plant's publishers (``command_applied``).
    interface
        ``voltages`` or ``cmd_vel``.
    follower
        The robot's plans.
    """

    def __init__(self, outputs: PlantOutputs, interface: str, follower: PlanFollower) -> None:
        self.outputs, self.interface, self.follower = outputs, interface, follower
        self.topic = PLAN_TOPICS[interface]
        self.msg_type = plan_type(interface)

    def read(self, msg: Any) -> CommandPlan | Unreadable:
        """The plan of a message (the follower's period), or why it cannot be read."""
        try:
            return plan_of_message(msg, self.follower.period_s)
        except PlanMessageError as exc:
            return Unreadable(exc.reason, str(exc))

    def refusal(self, item: CommandPlan | Unreadable, reason: str | None) -> list[Log]:
        """The log line of a plan the follower refused (none for one taken, older or a duplicate)."""
        if reason is None or reason in IGNORED:
            return []
        detail = item.detail if isinstance(item, Unreadable) else \
            f"basis {item.basis_s:.6f} s, {len(item.times_s)} entries"
        return [Log(Level.WARN, f"refused {self.topic} ({reason}: {detail}); the plans held stay "
                    f"({self.follower.counts['refused_plans']} refused so far)", "refused_plan", 1.0)]

    def messages(self, reports: list[AppliedReport]) -> list[Message]:
        """The reports as ``command_applied`` messages, oldest first."""
        pub = self.outputs.report_pub
        assert pub is not None
        return [(pub, applied_message(r.time_s, r.basis_s, r.entry_index, r.values, self.interface)
                 if r.basis_s is None or r.values is not None else
                 received_message(r.time_s, r.basis_s, self.interface, r.taken)) for r in reports]
