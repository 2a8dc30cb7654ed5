"""The controller node's output side: the publishers of what a `loop.controller_loop.ControllerLoop` answers.

`ControllerOutputs.send` publishes a loop's outputs (`loop.events`): the command (and in lockstep the bookkeeping of
the last answer, sent again when the plant resends a tick whose answer found no reader), zero, the plan, the
status, the predicted path, the enabled state, and the log lines (throttled per key). It also tells the loop
whether anyone reads the status and the path (`loop.controller_loop.Listeners`), so they are built only then.
The topics: `controller_node`'s docstring. Publishers use `ros.qos.publish_qos` (keep-all in lockstep).
"""

from __future__ import annotations

from collections.abc import Sequence

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Path
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, Float64MultiArray

from robotino_geom_mpc.loop.controller_loop import TRACKING_KEYS
from robotino_geom_mpc.loop.events import (Command, Diagnostic, EnabledChanged, Log, Output, PlanOut, PredictedPath,
                                           Resend, Waiting, Zero)
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.ros.controller_cdr import diagnostics_cdr
from robotino_geom_mpc.ros.messages import ODOM_FRAME, VOLTAGE_LABEL, path_cdr, three_values_template
from robotino_geom_mpc.ros.plans import PLAN_TOPICS, PlanWriter, plan_type
from robotino_geom_mpc.ros.qos import LATCHED_QOS, publish_acknowledged, publish_qos
from robotino_geom_mpc.ros.throttle import log_throttled

__all__ = ["ControllerOutputs", "TRACKING_KEYS"]

ZERO = (0.0, 0.0, 0.0)
_WAIT_LOG_PERIOD_S = 5.0  # throttle of the "waiting for ..." log
# the newest prediction only, kept for a late reader (a display); never blocks the loop
PATH_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class ControllerOutputs:
    """Publishers of the controller node and the last lockstep answer (module docstring).

    Parameters
    ----------
    node
        The controller node (publishers are created on it).
    lockstep
        Keep-all publishers, and an answer that went out before a reader matched is sent again when one does.
    frame_prefix
        Prefix of the ``odom`` frame of ``predicted_path`` (a namespaced robot's ``robot1/odom``).
    command_interface
        ``voltages``: the command is the wheel voltages [V] on ``wheel_voltages``; ``cmd_vel``: a base_link
        twist (v_x [m/s], v_y [m/s], theta' [rad/s]) on ``cmd_vel`` (geometry_msgs/Twist).
    plan_length
        With plans: the plans' length (``wheel_voltage_plan`` / ``cmd_vel_plan`` are published); None: no plans.
    predicted_path
        ``predicted_path`` is published (while subscribed); false: no publisher, the prediction never computed.
    """

    def __init__(self, node: Node, lockstep: bool, frame_prefix: str = "",
                 command_interface: str = "voltages", plan_length: int | None = None,
                 predicted_path: bool = True) -> None:
        self.node = node
        self.cmd_vel = command_interface == "cmd_vel"
        qos = publish_qos(lockstep)
        # lockstep: a newly matched plant gets an answer sent before it matched (realtime: the next tick's)
        matched = PublisherEventCallbacks(matched=self._on_command_matched) if lockstep else None
        if self.cmd_vel:
            self.command_pub = node.create_publisher(Twist, "cmd_vel", qos, event_callbacks=matched)
            self.twist = Twist()
        else:
            self.command_pub = node.create_publisher(Float64MultiArray, "wheel_voltages", qos, event_callbacks=matched)
            self.voltage_cdr = three_values_template(VOLTAGE_LABEL)
        self.diag_pub = node.create_publisher(DiagnosticArray, "diagnostics", qos)
        self.diag_keys: dict[tuple[str, ...], tuple[bytes, ...]] = {}  # the keys of a status, encoded once
        self.answered: tuple[int, bool, list[float]] | None = None  # stamp, delivered, command
        self.path_pub = node.create_publisher(Path, "predicted_path", PATH_QOS) if predicted_path else None
        self.path_frame = frame_prefix + ODOM_FRAME
        self.enabled_pub = node.create_publisher(Bool, "controller_enabled", LATCHED_QOS)
        self.plan_pub, self.plan_writer = None, None
        if plan_length is not None:
            self.plan_pub = node.create_publisher(plan_type(command_interface), PLAN_TOPICS[command_interface], qos)
            self.plan_writer = PlanWriter(command_interface, plan_length)

    def send_enabled(self, enabled: bool) -> None:
        """Publish the enabled state (latched)."""
        self.enabled_pub.publish(Bool(data=enabled))

    def send(self, outputs: list[Output]) -> None:
        """Publish (log) what a loop answered, in its order."""
        for out in outputs:
            if isinstance(out, Command):
                self.answer(out.stamp_ns, list(out.values))
            elif isinstance(out, Diagnostic):
                self.diagnose(out)
            elif isinstance(out, Zero):
                self.send_command(ZERO)
            elif isinstance(out, Log):
                log_throttled(self.node.get_logger(), out.level.name, out.text, out.throttle_s, out.key)
            elif isinstance(out, PlanOut):
                self.publish_plan(out.plan)
            elif isinstance(out, PredictedPath):
                self.publish_path(out)
            elif isinstance(out, Resend):
                self.deliver_answer()
            elif isinstance(out, EnabledChanged):
                self.send_enabled(out.enabled)
            elif isinstance(out, Waiting):
                log_throttled(self.node.get_logger(), "INFO", f"waiting: {self._waiting(out)}", _WAIT_LOG_PERIOD_S,
                              "waiting")

    # commands -----------------------------------------------------------------------------------
    def send_command(self, command: Sequence[float]) -> None:
        """Publish a command: wheel voltages [V], or the base_link twist with ``cmd_vel``."""
        if self.cmd_vel:
            msg = self.twist
            msg.linear.x, msg.linear.y, msg.angular.z = command
        else:
            msg = self.voltage_cdr.pack(*command)
        publish_acknowledged(self.node, self.command_pub, msg)

    def answer(self, stamp: int, command: list[float]) -> None:
        """Publish the answer to the odometry of `stamp` and remember whether a reader could receive it."""
        delivered = self.command_pub.get_subscription_count() > 0
        self.send_command(command)
        self.answered = (stamp, delivered, command)

    def deliver_answer(self) -> None:
        """Lockstep: publish the last answer again if it went out before any subscription matched."""
        if self.answered is not None and not self.answered[1] and self.command_pub.get_subscription_count() > 0:
            self.send_command(self.answered[2])
            self.answered = (self.answered[0], True, self.answered[2])

    def _on_command_matched(self, info: QoSPublisherMatchedInfo) -> None:
        if info.current_count_change > 0:
            self.deliver_answer()

    def publish_plan(self, plan: CommandPlan) -> None:
        """Publish a plan (plans over a link)."""
        assert self.plan_pub is not None and self.plan_writer is not None
        publish_acknowledged(self.node, self.plan_pub, self.plan_writer.encode(plan))

    # prediction ---------------------------------------------------------------------------------
    def path(self) -> bool:
        """True while a ``predicted_path`` subscription is matched (the prediction is computed only then)."""
        return self.path_pub is not None and self.path_pub.get_subscription_count() > 0

    def publish_path(self, path: PredictedPath) -> None:
        """Publish the predicted poses y(k+1) .. y(k+N) of a tick (header: its stamp; pose j: its time)."""
        assert self.path_pub is not None  # (`path`: asked only with a publisher)
        publish_acknowledged(self.node, self.path_pub, path_cdr(self.path_frame, path.stamp_ns, path.stamps_ns,
                                                                path.poses))

    # diagnostics --------------------------------------------------------------------------------
    def diagnostics(self) -> bool:
        """True while a diagnostics subscription is matched (building the array costs ~70 us a tick)."""
        return self.diag_pub.get_subscription_count() > 0

    def diagnose(self, status: Diagnostic) -> None:
        """Publish a status."""
        keys = self.diag_keys.get(status.keys)
        if keys is None:
            keys = self.diag_keys[status.keys] = tuple(key.encode() for key in status.keys)
        publish_acknowledged(self.node, self.diag_pub, diagnostics_cdr(
            status.stamp_ns, bytes((int(status.level),)), status.message, keys, status.values))

    # the watchdog's word ------------------------------------------------------------------------
    def _waiting(self, waiting: Waiting) -> str:
        """What the controller waits for, with the topic and its publishers."""
        node = self.node
        if waiting.what == "preview_of_stamp":
            topic = node.resolve_topic_name("reference_preview")
            return (f"the odometry of stamp {waiting.stamp_ns} ns waits {waiting.waited_s:.1f} s for the "
                    f"reference_preview of that stamp on {topic} ({node.count_publishers(topic)} publishers)")
        if waiting.what == "odometry":
            topic = node.resolve_topic_name("odom")
            heard = "since the start" if waiting.since_start else "since the last one"
            return (f"no odometry on {topic} for {waiting.waited_s:.1f} s {heard} "
                    f"({node.count_publishers(topic)} publishers)")
        topic = node.resolve_topic_name("reference_preview")
        return f"no reference_preview on {topic} yet ({node.count_publishers(topic)} publishers)"
