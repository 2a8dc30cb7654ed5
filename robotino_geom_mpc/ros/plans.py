"""Packetized commands on ROS: plans (`network.plan.CommandPlan`) and the robot's ``command_applied`` reports.

Messages (standard types; every time is the ROBOT's clock)
---------------------------------------------------------
``wheel_voltage_plan``  trajectory_msgs/JointTrajectory: header.stamp = the plan's basis (the stamp of the
                        odometry it was computed from); joint_names = the three wheel joints (as the URDF and
                        ``joint_states``); points[i].time_from_start = times_s[i] - basis (JointTrajectory's time
                        base is header.stamp, as ros2_controllers' joint_trajectory_controller reads it);
                        points[i].effort = the three voltages [V].
``cmd_vel_plan``        trajectory_msgs/MultiDOFJointTrajectory, the same stamps; joint_names ["base_link"];
                        points[i].velocities[0] = the body twist in base_link (linear.x, linear.y, angular.z).
``command_applied``     trajectory_msgs/JointTrajectory, one event per message, about one plan: header.stamp =
                        the plan's basis. One point:
                        * with values (``effort`` = the voltages [V], or ``velocities`` = the twist (v_x, v_y,
                          omega) for cmd_vel): a control period applied, time_from_start = the period's start -
                          basis; positions = [the entry index]; index -1: no plan held, the values are zero
                          (header.stamp = the period's start, time_from_start 0);
                        * without values: the plan was received, time_from_start = its receipt time - basis;
                          positions = [1] if the robot's buffer took it, [0] if not (older than one held,
                          or refused).
                        joint_names = the wheel joints (voltages) or `TWIST_AXES` (cmd_vel).
                        Why JointTrajectory: the report is the part of the plan that took effect, so it has the
                        plan's own type, time base and joint names; any ROS tool (``ros2 topic echo``, rqt_plot,
                        rosbags) reads it, and an ament_python package cannot build a message of its own.

The plan's period (how long its last entry lasts) is not in the message: it is the receiver's control period.

The controller sends its plans as CDR bytes (`PlanWriter`: a `cdr.CdrTemplate` per length; rclpy's building
and conversion of a 25-point message cost 0.4 ms a tick).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Twist
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint, MultiDOFJointTrajectory, \
    MultiDOFJointTrajectoryPoint

from robotino_geom_mpc.description.urdf import BASE_LINK, JOINT_NAMES
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.loop.events import AppliedReport
from robotino_geom_mpc.loop.inputs import REPORT_WINDOW_S, report_problem
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.ros.cdr import CdrTemplate
from robotino_geom_mpc.ros.decode import STAMP_FIELDS

if TYPE_CHECKING:
    from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController

__all__ = ["AppliedReport", "PLAN_TOPICS", "PlanMessageError", "PlanWriter", "TWIST_AXES",
           "applied_message", "plan_message", "plan_of_message", "plan_type", "received_message",
           "REPORT_WINDOW_S", "report_near", "report_of_message", "take_report"]

PLAN_TOPICS = {"voltages": "wheel_voltage_plan", "cmd_vel": "cmd_vel_plan"}
TWIST_AXES = ("base_link_x", "base_link_y", "base_link_yaw")  # command_applied's names of a twist's values


class PlanMessageError(RobotinoError, ValueError):
    """A plan or report message that cannot be read; `reason` is a `PlanBuffer` refusal key."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


def _seconds(sec: int, nanosec: int) -> float:
    """A stamp in seconds as the nodes compute it from integer nanoseconds (ns * 1e-9: a plan's basis is a key
    that must compare equal to the controller's own).
    """
    return (sec * 1_000_000_000 + nanosec) * 1e-9


def _stamp(time_s: float) -> tuple[int, int]:
    ns = int(round(time_s * 1e9))
    return ns // 1_000_000_000, ns % 1_000_000_000


def _duration(seconds: float) -> Duration:
    sec, nanosec = _stamp(seconds)
    return Duration(sec=sec, nanosec=nanosec)


def plan_type(interface: str) -> type:
    """The plan message type of `interface` (``voltages`` or ``cmd_vel``)."""
    return MultiDOFJointTrajectory if interface == "cmd_vel" else JointTrajectory


def plan_message(plan: CommandPlan, interface: str) -> JointTrajectory | MultiDOFJointTrajectory:
    """The plan as ``wheel_voltage_plan`` (`interface` voltages) or ``cmd_vel_plan`` (cmd_vel)."""
    if interface == "cmd_vel":
        msg = MultiDOFJointTrajectory(joint_names=[BASE_LINK])
        for t, (vx, vy, w) in zip(plan.times_s, plan.entries):
            twist = Twist()
            twist.linear.x, twist.linear.y, twist.angular.z = float(vx), float(vy), float(w)
            msg.points.append(MultiDOFJointTrajectoryPoint(velocities=[twist],
                                                           time_from_start=_duration(t - plan.basis_s)))
    else:
        msg = JointTrajectory(joint_names=list(JOINT_NAMES))
        msg.points = [JointTrajectoryPoint(effort=[float(v) for v in entry],
                                           time_from_start=_duration(t - plan.basis_s))
                      for t, entry in zip(plan.times_s, plan.entries)]
    msg.header.stamp.sec, msg.header.stamp.nanosec = _stamp(plan.basis_s)
    return msg


def plan_of_message(msg: JointTrajectory | MultiDOFJointTrajectory, period_s: float) -> CommandPlan:
    """The `CommandPlan` a plan message carries (its last entry lasting `period_s`).

    Raises
    ------
    PlanMessageError
        ``length``: no point, or a point without exactly three values (or one twist); ``stamp``: a header
        stamp or time_from_start that is no time. NaN and the times' order are `PlanBuffer.offer`'s to refuse.
    """
    stamp = msg.header.stamp
    if stamp.sec < 0 or not 0 <= stamp.nanosec < 1_000_000_000:
        raise PlanMessageError(f"header stamp ({stamp.sec} s, {stamp.nanosec} ns) is no time", "stamp")
    if not msg.points:
        raise PlanMessageError("a plan without points", "length")
    basis = _seconds(stamp.sec, stamp.nanosec)
    times, entries = [], []
    # by the points' fields, not the class: a recording's messages (rosbags, the bag readers) are classes of their own
    twists = hasattr(msg.points[0], "transforms")  # a MultiDOFJointTrajectoryPoint
    for i, point in enumerate(msg.points):
        if twists:
            if len(point.velocities) != 1:
                raise PlanMessageError(f"point {i} has {len(point.velocities)} twists (need 1)", "length")
            twist = point.velocities[0]
            entries.append((twist.linear.x, twist.linear.y, twist.angular.z))
        else:
            if len(point.effort) != 3:
                raise PlanMessageError(f"point {i} has {len(point.effort)} voltages (need 3)", "length")
            u1, u2, u3 = point.effort
            entries.append((float(u1), float(u2), float(u3)))
        offset = point.time_from_start
        if not 0 <= offset.nanosec < 1_000_000_000:
            raise PlanMessageError(f"point {i}: time_from_start is no duration", "stamp")
        times.append(basis + _seconds(offset.sec, offset.nanosec))
    return CommandPlan(basis_s=basis, times_s=tuple(times), entries=tuple(entries), period_s=period_s)


def _report(basis_s: float | None, time_s: float, interface: str) -> JointTrajectory:
    msg = JointTrajectory(joint_names=list(TWIST_AXES if interface == "cmd_vel" else JOINT_NAMES))
    base = time_s if basis_s is None else basis_s
    msg.header.stamp.sec, msg.header.stamp.nanosec = _stamp(base)
    msg.points = [JointTrajectoryPoint(time_from_start=_duration(time_s - base))]
    return msg


def applied_message(time_s: float, basis_s: float | None, index: int, values, interface: str) -> JointTrajectory:
    """``command_applied`` of the period starting at `time_s`: entry `index` of plan `basis_s` (None: no plan,
    `values` zero, index -1).
    """
    msg = _report(basis_s, time_s, interface)
    point = msg.points[0]
    point.positions = [float(index if basis_s is not None else -1)]
    if interface == "cmd_vel":
        point.velocities = [float(v) for v in values]
    else:
        point.effort = [float(v) for v in values]
    return msg


def received_message(receipt_s: float, basis_s: float, interface: str, taken: bool) -> JointTrajectory:
    """``command_applied`` of the receipt of plan `basis_s` at `receipt_s` (robot clock), `taken` by the buffer."""
    msg = _report(basis_s, receipt_s, interface)
    msg.points[0].positions = [1.0 if taken else 0.0]
    return msg


def report_of_message(msg: JointTrajectory) -> AppliedReport:
    """The `AppliedReport` of a ``command_applied`` message; `PlanMessageError` if it is not one."""
    stamp = msg.header.stamp
    if len(msg.points) != 1 or stamp.sec < 0 or not 0 <= stamp.nanosec < 1_000_000_000:
        raise PlanMessageError(f"a report has one point and a stamp, got {len(msg.points)} points", "length")
    point = msg.points[0]
    base = _seconds(stamp.sec, stamp.nanosec)
    offset = point.time_from_start
    time_s = base + _seconds(offset.sec, offset.nanosec)
    values = tuple(point.velocities) if len(point.velocities) == 3 else tuple(point.effort)
    if not values:
        return AppliedReport(time_s, base, -1, None, bool(point.positions) and point.positions[0] > 0.5)
    if len(values) != 3 or len(point.positions) != 1 or not all(math.isfinite(v) for v in (*values, *point.positions)):
        raise PlanMessageError("an applied report has three finite values and its index", "length")
    index = int(point.positions[0])
    v1, v2, v3 = values
    return AppliedReport(time_s, base if index >= 0 else None, max(index, -1), (float(v1), float(v2), float(v3)))


def report_near(msg: JointTrajectory, newest_s: float | None, window_s: float = REPORT_WINDOW_S) -> AppliedReport:
    """`report_of_message`, refused (`PlanMessageError`, reason ``future`` or ``past``) when its time is more than
    `window_s` from the newest odometry stamp `newest_s` (a stamp far off; None: no odometry yet, any time).
    """
    report = report_of_message(msg)
    problem = report_problem(report.time_s, newest_s, window_s)
    if problem is not None:
        raise PlanMessageError(problem[1], problem[0])
    return report


def take_report(controller: DelayCompensatingController, msg: JointTrajectory, newest_s: float | None,
                window_s: float = REPORT_WINDOW_S) -> AppliedReport:
    """`report_near`, handed to `controller`: a receipt (``report_receipt``) or an applied period
    (``report_applied``); `PlanMessageError` for a report refused. The controller node and ``regress`` alike.
    """
    report = report_near(msg, newest_s, window_s)
    if report.values is None and report.basis_s is not None:  # a receipt (it always names its plan)
        controller.report_receipt(report.basis_s, report.time_s, report.taken)
    else:
        controller.report_applied(report.time_s, report.basis_s, max(report.entry_index, 0))
    return report


class PlanWriter:
    """Plan messages of `interface` as CDR bytes, without rclpy's message conversions (a tenth of the time).

    `encode` patches the stamps and entries into a `cdr.CdrTemplate` of the plan's length (made on first use,
    or here for `length`: about 0.1 s); the bytes are those of `plan_message`, and a publisher of the plan
    type sends them as they are.
    """

    def __init__(self, interface: str, length: int | None = None) -> None:
        self.interface = interface
        self._templates: dict[int, CdrTemplate] = {}
        if length is not None:
            self._templates[length] = self._template(length)

    def _template(self, length: int) -> CdrTemplate:
        values = (("velocities[0].linear.x", "velocities[0].linear.y", "velocities[0].angular.z")
                  if self.interface == "cmd_vel" else ("effort[0]", "effort[1]", "effort[2]"))
        fields = STAMP_FIELDS + tuple(f"points[{i}].{f}" for i in range(length)
                                      for f in ("time_from_start.sec", "time_from_start.nanosec", *values))
        zero = (0.0, 0.0, 0.0)
        skeleton = CommandPlan(0.0, tuple(float(i) for i in range(length)), (zero,) * length, 1.0)
        return CdrTemplate(plan_message(skeleton, self.interface), fields)

    def encode(self, plan: CommandPlan) -> bytes:
        """The serialized `plan_message(plan)`."""
        length = len(plan.times_s)
        template = self._templates.get(length)
        if template is None:
            template = self._templates[length] = self._template(length)
        values: list[float | int] = [*_stamp(plan.basis_s)]
        for t, entry in zip(plan.times_s, plan.entries):
            values += (*_stamp(t - plan.basis_s), *map(float, entry))
        return template.pack(*values)
