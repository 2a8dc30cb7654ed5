"""The controller node's plans (``plans`` true): delay-compensated, packetized commands and the robot's reports.

With ``plans`` the node makes, per odometry, a `network.plan.CommandPlan` with
`control.delay_compensation.DelayCompensatingController` (the state predicted from the odometry's stamp to the
plan's first action time through the commands the robot applies meanwhile, the MPC rolled out over
``control.plan_length`` periods, the lead from the measured round trips) and publishes it on
``wheel_voltage_plan`` (``command_interface`` voltages) or ``cmd_vel_plan`` (`ros.plans`); the plain
``wheel_voltages`` / ``cmd_vel`` carry the plan's first entry (for who wants them). It needs the reference over
`DelayCompensatingController.preview_length` periods: the trajectory node's ``preview_points``.

It reads the robot's ``command_applied`` (trajectory_msgs/JointTrajectory, `ros.plans`): each plan's receipt time
and each period's applied entry, the robot's clock, and hands them to the controller. A report that cannot be
read (wrong length, NaN) or whose time is more than ``report_window_s`` from the newest odometry stamp (a
stamp far in the future or the past) is refused: logged (throttled), counted (``refused_reports``), ignored.
In lockstep a report that arrives while an odometry before it waits (for its preview) is held back until that
odometry is planned (`hold_into`, `take`): each plan is made with the reports that came before its odometry, in
the order the robot sent them, as `offline.networked` makes it, whichever of the trajectory and the plant is
faster.

Diagnostics (`LINK_KEYS`, on every status): the round trip (robot's receipt of a plan - its odometry stamp:
the up-link's delay, the controller's time and the down-link's delay, one clock) mean, jitter (standard
deviation) and the lead's quantile [s], the lead [periods], plans sent / received / lost, odometries received /
missing (lost on the up-link) / stale (reordered or duplicated), periods the robot had no plan
(``exhausted_periods``), refused reports, and every report received so far (``reports_received``: with each
odometry's status, the replay (`recording.regress_plans`) hands the controller the reports in the order it got
them against its odometry).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectory

from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.ros.plans import PLAN_TOPICS, PlanMessageError, PlanWriter, plan_type, take_report
from robotino_geom_mpc.ros.qos import publish_acknowledged, publish_qos
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["ControllerPlans", "LINK_KEYS"]

LINK_KEYS = ("round_trip_mean_s", "round_trip_jitter_s", "round_trip_quantile_s", "lead_periods", "plans_sent",
             "plans_received", "plans_lost", "odometry_received", "odometry_missing", "odometry_stale",
             "exhausted_periods", "refused_reports", "reports_received")
_STAT_FIELDS = LINK_KEYS[:-2]


class ControllerPlans:
    """The plan side of a controller node (see the module docstring).

    Parameters
    ----------
    node
        The controller node (publishers, subscription, logger).
    robot, control
        The controller's model and settings.
    interface
        ``voltages`` or ``cmd_vel``.
    lockstep
        Keep-all publishers.
    report_window_s
        How far a report's time may be from the newest odometry stamp.
    """

    def __init__(self, node: Node, robot: RobotinoParams, control: ControlParams, interface: str, lockstep: bool,
                 report_window_s: float) -> None:
        self.node, self.interface, self.window_s = node, interface, report_window_s
        self.controller = DelayCompensatingController(robot, control, interface)
        msg_type = plan_type(interface)
        self.pub = node.create_publisher(msg_type, PLAN_TOPICS[interface], publish_qos(lockstep))
        self.sub = node.create_subscription(JointTrajectory, "command_applied", self._on_report,
                                            publish_qos(lockstep))  # every report (keep-all in lockstep)
        self.newest_stamp_s: float | None = None
        self.refused_reports = 0
        self.reports_received = 0  # command_applied messages handed on, taken or refused (regress replays them so)
        # lockstep: the list of the reports held for the last odometry still waiting (None: none waits)
        self.hold_into: Callable[[], list[JointTrajectory] | None] = lambda: None
        self.writer = PlanWriter(interface, control.plan_length)

    @property
    def preview_length(self) -> int:
        """Rows of reference after the odometry's stamp a plan needs."""
        return self.controller.preview_length

    def rebuild(self, robot: RobotinoParams, control: ControlParams) -> None:
        """A new controller (new parameters): plans, reports and round trips start over."""
        self.controller = DelayCompensatingController(robot, control, self.interface)

    def plan(self, stamp_ns: int, X, preview) -> CommandPlan | None:
        """The plan of the odometry of `stamp_ns` (None: not newer than one taken); published."""
        self.newest_stamp_s = stamp_ns * 1e-9
        plan = self.controller.plan(stamp_ns * 1e-9, X, preview)
        if plan is not None:
            publish_acknowledged(self.node, self.pub, self.writer.encode(plan))
        return plan

    def take(self, reports: list[JointTrajectory]) -> None:
        """Hand on held reports, in the order they came."""
        for msg in reports:
            self._take(msg)

    def _on_report(self, msg: JointTrajectory) -> None:
        held = self.hold_into()
        if held is not None:
            held.append(msg)
            return
        self._take(msg)

    def _take(self, msg: JointTrajectory) -> None:
        self.reports_received += 1
        try:
            take_report(self.controller, msg, self.newest_stamp_s, self.window_s)
        except PlanMessageError as exc:
            self.refused_reports += 1
            warn_throttled(self.node.get_logger(), f"refused command_applied ({exc.reason}: {exc}); "
                                        f"{self.refused_reports} refused so far", 1.0)

    def values(self) -> list[str]:
        """The diagnostic values of `LINK_KEYS`."""
        stats = self.controller.statistics()
        out = []
        for name in _STAT_FIELDS:
            value = getattr(stats, name)
            out.append("nan" if isinstance(value, float) and math.isnan(value) else
                       f"{value:.6f}" if isinstance(value, float) else str(value))
        return out + [str(self.refused_reports), str(self.reports_received)]
