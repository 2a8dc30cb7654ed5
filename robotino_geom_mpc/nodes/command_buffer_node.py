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
                                (the driver has no command timeout: the last zero holds the robot; a joystick
                                may take over)
           ``command_applied``  trajectory_msgs/JointTrajectory (`ros.plans`): each period sent (its start time,
                                the plan's basis, the entry, the twist) and each plan received (its receipt time,
                                taken or not)
           ``diagnostics``      diagnostic_msgs/DiagnosticArray once a second: plans accepted, refused per reason,
                                periods exhausted, the last receipt's age over the plan's basis (one-way delay of
                                the plan plus the odometry's age at the controller: the loop's round trip)

One controller at a time: the buffer pairs with the first publisher of ``cmd_vel_plan`` after its start or a
``~/release`` (std_srvs/Trigger) and refuses the plans of any other while the paired one has sent within
``pairing.lease_s`` (`loop.source_pairing.SourcePairing`; the publishers told apart by `ros.source_gate.SourceGate`):
a refused plan is not offered to the buffer (the paired controller's plans go on), it is counted
(``refused_second_source``), a throttled warning and the diagnostics (``paired_source``, ``second_source``) name
the publishers from the ROS graph.

Clock: the robot's (the node clock; ``use_sim_time`` honoured). A plan stamped far in the future or the past of
it is refused (`PlanBuffer.offer`'s ``future`` / ``past``), as one with NaN, a wrong length or non-increasing
times: logged (throttled), counted, the previous plan (or zero) stays.

Parameters: ``control.period_s`` (the plans' period; the config file's value), `BUFFER_SPECS` and ``pairing.lease_s``.
"""

from __future__ import annotations

import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Twist
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

from robotino_geom_mpc.loop.plan_follower import IGNORED, PlanDispatcher, PlanFollower
from robotino_geom_mpc.loop.source_pairing import SourcePairing
from robotino_geom_mpc.params.specs import CONTROL_SPECS, ParamSpec
from robotino_geom_mpc.ros.parameters import SpecParameters, spec_defaults
from robotino_geom_mpc.ros.plans import PlanMessageError, applied_message, plan_of_message, received_message
from robotino_geom_mpc.ros.qos import CONTROL_QOS, PUBLISH_QOS
from robotino_geom_mpc.ros.source_gate import PAIRING_DEFAULTS, PAIRING_SPECS, SourceGate, WithInfo
from robotino_geom_mpc.ros.spin import clock_s, run_node
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
    """The command buffer node (see the module docstring): plan messages in, `loop.plan_follower.PlanDispatcher`
    polled on the node clock, cmd_vel and reports out.
    """

    def __init__(self) -> None:
        super().__init__("robotino_command_buffer")
        period_spec = tuple(s for s in CONTROL_SPECS if s.name == "control.period_s")
        self.params = SpecParameters(self, period_spec + BUFFER_SPECS + PAIRING_SPECS,
                                     {**spec_defaults(period_spec), **_DEFAULTS, **PAIRING_DEFAULTS},
                                     self._on_params, fixed=("control.period_s",))
        self.pairing = SourcePairing(1)
        self.pairing.set_lease(self.params["pairing.lease_s"])
        self.period_s = self.params["control.period_s"]
        self.follower = PlanFollower(self.period_s)
        self.dispatcher = PlanDispatcher(self.follower, self.params["idle_after_s"])
        self.cmd_pub = self.create_publisher(Twist, "cmd_vel", CONTROL_QOS)
        self.report_pub = self.create_publisher(JointTrajectory, "command_applied", PUBLISH_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", PUBLISH_QOS)
        self.gate = SourceGate(self, "cmd_vel_plan")
        self.plan_sub = self.create_subscription(MultiDOFJointTrajectory, "cmd_vel_plan", WithInfo(self._on_plan),
                                                 CONTROL_QOS)
        self.release_srv = self.create_service(Trigger, "~/release", self._on_release)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(POLL_S, self._tick, clock=steady)
        self.diag_timer = self.create_timer(1.0, self._diagnose, clock=steady)
        self.get_logger().info(f"command buffer ready (Ts = {self.period_s:g} s): cmd_vel_plan -> cmd_vel")

    def _now_s(self) -> float:
        return clock_s(self)

    def _on_params(self, changed: dict) -> None:
        self.pairing.set_lease(self.params["pairing.lease_s"])

    def _on_release(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/release: the next controller to send plans takes the robot."""
        response.success, response.message = True, self.gate.released(self.pairing, self.pairing.release())
        return response

    def _on_plan(self, msg: MultiDOFJointTrajectory, info: dict[str, Any]) -> None:
        source = self.gate.source(info)
        if not self.pairing.admit(source, time.monotonic_ns()):
            self.gate.refused(self.pairing, source)
            return
        self.gate.note(self.pairing)
        reason: str | None
        try:
            plan = plan_of_message(msg, self.period_s)
        except PlanMessageError as exc:
            reason, detail = exc.reason, str(exc)
            self.follower.refuse(reason)
        else:
            reason = self.dispatcher.take(plan, self._now_s())
            detail = f"basis {plan.basis_s:.6f} s, {len(plan.times_s)} entries"
        self._publish_reports()
        if reason is not None and reason not in IGNORED:
            warn_throttled(self.get_logger(), f"refused a plan ({reason}: {detail}); the previous plan (or zero) stays "
                           f"({self.follower.counts['refused_plans']} refused so far)", 1.0)

    def _tick(self) -> None:
        """Each poll: what the dispatcher sends now (`PlanDispatcher.poll`)."""
        if not self.dispatcher.active:
            return
        values = self.dispatcher.poll(self._now_s())
        if values is not None:
            twist = Twist()
            twist.linear.x, twist.linear.y, twist.angular.z = values
            self.cmd_pub.publish(twist)
            self._publish_reports()
        elif not self.dispatcher.active:
            self.get_logger().info("every plan used up: robot stopped, cmd_vel idle until the next plan")

    def _publish_reports(self) -> None:
        for r in self.follower.pop_reports():
            self.report_pub.publish(applied_message(r.time_s, r.basis_s, r.entry_index, r.values, "cmd_vel")
                                    if r.basis_s is None or r.values is not None else
                                    received_message(r.time_s, r.basis_s, "cmd_vel", r.taken))

    def _diagnose(self) -> None:
        counts = self.follower.counts
        refused = {**dict.fromkeys(_ERRORS, 0), **self.follower.refused}
        status = DiagnosticStatus(name=STATUS_NAME, hardware_id="robotino",
                                  level=DiagnosticStatus.WARN if counts["refused_plans"] or self.pairing.refused
                                  else DiagnosticStatus.OK,
                                  message="active" if self.dispatcher.active else "idle")
        values = {"refused": counts["refused_plans"], **{f"refused_{k}": v for k, v in refused.items()},
                  "ignored_older_or_duplicate": counts["ignored_plans"],
                  "exhausted_periods": counts["exhausted_periods"],
                  "last_round_trip_s": f"{self.dispatcher.round_trip_s:.6f}", **self.gate.status(self.pairing)}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(msg)

    def on_stop(self) -> None:
        """Leave the robot at zero twist as the node stops (`ros.spin.run_node`)."""
        if self.dispatcher.active:
            self.cmd_pub.publish(Twist())


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc command_buffer_node``."""
    return run_node(CommandBufferNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
