"""Robot-side command buffer: takes the controller's plans over the network, drives the Robotino's ``cmd_vel``.

It runs on the robot's PC beside the driver (e.g. robotino_ros2's node, which takes geometry_msgs/Twist on
``cmd_vel``), so the one hop that matters for timing, buffer -> driver, is local, and the radio's delay, jitter
and losses are covered by the plans (`network.plan.PlanBuffer`): each period the entry of the newest plan held
that covers it goes out; a late or lost plan is covered by the previous one; a duplicate or older one is ignored.

Topics (relative names)
-----------------------
subscribes ``cmd_vel_plan``     trajectory_msgs/MultiDOFJointTrajectory (`ros.plans`), times in the robot's clock
publishes  ``cmd_vel``          geometry_msgs/Twist in base_link, to the driver: from the first plan on, at each
                                entry's start time (within `POLL_S`; the entry of a period is the one the plans
                                held at its start, held to its end); zero twist once every plan is
                                used up (the robot stops) for ``idle_after_s``, then nothing until the next plan
                                (the driver's own timeout holds it, and a joystick may take over)
           ``command_applied``  trajectory_msgs/JointTrajectory (`ros.plans`): each period sent (its start time,
                                the plan's basis, the entry, the twist) and each plan received (its receipt time,
                                taken or not)
           ``diagnostics``      diagnostic_msgs/DiagnosticArray once a second: plans accepted, refused per reason,
                                periods exhausted, the last receipt's age over the plan's basis (one-way delay of
                                the plan plus the odometry's age at the controller: the loop's round trip)

Clock: the robot's (the node clock; ``use_sim_time`` honoured). A plan stamped far in the future or the past of
it is refused (`PlanBuffer.offer`'s ``future`` / ``past``), as one with NaN, a wrong length or non-increasing
times: logged (throttled), counted, the previous plan (or zero) stays.

Parameters: ``control.period_s`` (the plans' period; the config file's value) and `BUFFER_SPECS`.
"""

from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Twist
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S, PlanBuffer
from robotino_geom_mpc.params.specs import CONTROL_SPECS, ParamSpec
from robotino_geom_mpc.ros.parameters import SpecParameters, spec_defaults
from robotino_geom_mpc.ros.plans import IGNORED, applied_message, offer_plan
from robotino_geom_mpc.ros.qos import CONTROL_QOS, PUBLISH_QOS
from robotino_geom_mpc.ros.spin import run_node
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["BUFFER_SPECS", "CommandBufferNode", "POLL_S", "STATUS_NAME", "main"]

STATUS_NAME = "robotino_geom_mpc: command_buffer"
BUFFER_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("idle_after_s", float, "After this long with every plan used up (zero twist sent every period), "
              "stop publishing cmd_vel until the next plan", "s", 0.0, 3600.0, False),
)
_DEFAULTS = {"idle_after_s": 1.0}
POLL_S = 0.001  # a steady timer polls the plans this often: an entry goes out within it of its start time (a
# timer re-armed to each entry's start is what rclpy's events executor loses, see robotino_sim_node.radio)
_ERRORS = ("nan", "length", "times", "future", "past", "stamp")


class CommandBufferNode(Node):
    """The command buffer node (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__("robotino_command_buffer")
        period_spec = tuple(s for s in CONTROL_SPECS if s.name == "control.period_s")
        self.params = SpecParameters(self, period_spec + BUFFER_SPECS, {**spec_defaults(period_spec), **_DEFAULTS},
                                     fixed=("control.period_s",))
        self.period_s = self.params["control.period_s"]
        self.buffer = PlanBuffer()
        self.refused = dict.fromkeys(_ERRORS, 0)
        self.ignored = 0  # older or duplicate plans
        self.exhausted_periods = 0
        self.period_end_s = -math.inf  # when the entry sent last stops running
        self.next_zero_s = -math.inf  # every plan used up: when the next zero twist goes out
        self.exhausted_since: float | None = None
        self.round_trip_s = math.nan
        self.active = False  # a plan was taken and the idle time has not run out
        self.cmd_pub = self.create_publisher(Twist, "cmd_vel", CONTROL_QOS)
        self.report_pub = self.create_publisher(JointTrajectory, "command_applied", PUBLISH_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", PUBLISH_QOS)
        self.plan_sub = self.create_subscription(MultiDOFJointTrajectory, "cmd_vel_plan", self._on_plan, CONTROL_QOS)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(POLL_S, self._tick, clock=steady)
        self.diag_timer = self.create_timer(1.0, self._diagnose, clock=steady)
        self.get_logger().info(f"command buffer ready (Ts = {self.period_s:g} s): cmd_vel_plan -> cmd_vel")

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_plan(self, msg: MultiDOFJointTrajectory) -> None:
        now = self._now_s()
        reason, detail, plan, receipt = offer_plan(self.buffer, msg, self.period_s, now, "cmd_vel")
        if receipt is not None:
            self.report_pub.publish(receipt)
        if reason in IGNORED:
            self.ignored += 1
            return
        if reason is not None or plan is None:  # (plan is None only with a reason)
            self.refused[reason] = self.refused.get(reason, 0) + 1
            warn_throttled(self.get_logger(), f"refused a plan ({reason}: {detail}); the previous plan (or zero) stays "
                                   f"({sum(self.refused.values())} refused so far)", 1.0)
            return
        self.round_trip_s = now - plan.basis_s
        self.active = True  # the next poll sends what runs now (zero before the plan's first entry)

    def _tick(self) -> None:
        """Each poll: at a period's start, the entry the plans held then give, held to the period's end.

        A plan taken within a period acts from the next one, as the plant's `PlantPlans.period_command` and the
        controller's `control.plan_history` have it. Every plan used up: a zero twist once a period, for
        ``idle_after_s``.
        """
        if not self.active:
            return
        now = self._now_s()
        if now < self.period_end_s - TIME_TOLERANCE_S:  # the entry sent last still runs
            return
        applied = self.buffer.command_at(now)
        if applied is None:
            start = now if self.exhausted_since is None else self.exhausted_since
            self.exhausted_since, self.period_end_s = start, -math.inf  # a plan may start at any poll
            if now - start >= self.params["idle_after_s"]:
                self.active = False
                self.get_logger().info("every plan used up: robot stopped, cmd_vel idle until the next plan")
            elif now >= self.next_zero_s:
                self.exhausted_periods += 1
                self.next_zero_s = now + self.period_s
                self._send(now, None, -1, (0.0, 0.0, 0.0))
            return
        self.exhausted_since, self.next_zero_s = None, -math.inf
        begin, self.period_end_s = self.buffer.entry_span(applied, self.period_s)
        self._send(begin, applied.basis_s, applied.entry_index, applied.values)

    def _send(self, time_s: float, basis_s: float | None, index: int, values) -> None:
        twist = Twist()
        twist.linear.x, twist.linear.y, twist.angular.z = (float(v) for v in values)
        self.cmd_pub.publish(twist)
        self.report_pub.publish(applied_message(time_s, basis_s, index, values, "cmd_vel"))

    def _diagnose(self) -> None:
        refused = sum(self.refused.values())
        status = DiagnosticStatus(name=STATUS_NAME, hardware_id="robotino",
                                  level=DiagnosticStatus.WARN if refused else DiagnosticStatus.OK,
                                  message="active" if self.active else "idle")
        values = {"refused": refused, **{f"refused_{k}": v for k, v in self.refused.items()},
                  "ignored_older_or_duplicate": self.ignored, "exhausted_periods": self.exhausted_periods,
                  "last_round_trip_s": f"{self.round_trip_s:.6f}"}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(msg)

    def on_stop(self) -> None:
        """Leave the robot at zero twist as the node stops (`ros.spin.run_node`)."""
        if self.active:
            self.cmd_pub.publish(Twist())


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc command_buffer_node``."""
    return run_node(CommandBufferNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
