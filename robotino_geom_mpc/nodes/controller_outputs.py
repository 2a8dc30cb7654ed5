"""The controller node's output side: the publishers of what a `loop.controller_loop.ControllerLoop` answers.

`ControllerOutputs.send` publishes a loop's outputs (`loop.events`): the command, zero, the plan (in lockstep the
answers the plant reads, the commands or with plans the plans, are held until their publisher has matched its
``lockstep_command_readers``, then sent once, in order), the
status, the predicted path, the enabled state, and the log lines (throttled per key). It also tells the loop
whether anyone reads the status and the path (`loop.controller_loop.Listeners`), so they are built only then.
The topics: `controller_node`'s docstring. Publishers use `ros.qos.publish_qos` (keep-all in lockstep).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Path
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, Float64MultiArray

from robotino_geom_mpc.loop.controller_loop import TRACKING_KEYS
from robotino_geom_mpc.loop.events import (Command, Diagnostic, EnabledChanged, Log, Output, PlanOut, PredictedPath,
                                           Resend, Waiting, Zero)
from robotino_geom_mpc.ros.controller_cdr import diagnostics_cdr
from robotino_geom_mpc.ros.messages import ODOM_FRAME, VOLTAGE_LABEL, path_cdr, three_values_template
from robotino_geom_mpc.ros.plans import PLAN_TOPICS, PlanWriter, plan_type
from robotino_geom_mpc.ros.qos import LATCHED_QOS, publish_acknowledged, publish_qos
from robotino_geom_mpc.ros.throttle import log_throttled, warn_throttled

__all__ = ["ControllerOutputs", "TRACKING_KEYS"]

ZERO = (0.0, 0.0, 0.0)
_WAIT_LOG_PERIOD_S = 5.0  # throttle of the "waiting for ..." log
_HOLD_REPORT_AFTER_S = 1.0  # a shorter hold of an answer is discovery at work: not reported (as the plant's wait)
# the newest prediction only, kept for a late reader (a display); never blocks the loop
PATH_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class ControllerOutputs:
    """Publishers of the controller node and the last lockstep answer (module docstring).

    Parameters
    ----------
    node
        The controller node (publishers are created on it).
    lockstep
        Keep-all publishers, and the answers held until their readers have matched (`command_readers`).
    frame_prefix
        Prefix of the ``odom`` frame of ``predicted_path`` (a namespaced robot's ``robot1/odom``).
    command_interface
        ``voltages``: the command is the wheel voltages [V] on ``wheel_voltages``; ``cmd_vel``: a base_link
        twist (v_x [m/s], v_y [m/s], theta' [rad/s]) on ``cmd_vel`` (geometry_msgs/Twist).
    plan_length
        With plans: the plans' length (``wheel_voltage_plan`` / ``cmd_vel_plan`` are published); None: no plans.
    predicted_path
        ``predicted_path`` is published (while subscribed); false: no publisher, the prediction never computed.
    plain_command
        With plans: the plain command (the plan's first entry, zero) is published too; false: only the plans
        (a robot-side buffer drives the robot's ``cmd_vel``).
    command_readers
        Lockstep: the readers the publisher of the answers (the command's, with plans the plan's) must have matched
        before the first answer goes out (the plant's, and a recorder's: matching is per writer and reader, so the
        controller's writer can match the recorder before the plant, and an answer sent then never reaches the
        plant). Until then the answers are held, and they go out once, in order, when the readers have matched;
        after that one matched reader is enough (none: held until one matches). A zero outside the ticks (a
        refused input, without plans) queues behind them.
    """

    def __init__(self, node: Node, lockstep: bool, frame_prefix: str = "",
                 command_interface: str = "voltages", plan_length: int | None = None,
                 predicted_path: bool = True, command_readers: int = 1, plain_command: bool = True) -> None:
        self.node = node
        self.readers_needed = command_readers if lockstep else 0  # until first met; then 1
        self.cmd_vel = command_interface == "cmd_vel"
        self.plans = plan_length is not None
        self.plain = plain_command or not self.plans  # the plain command is published
        qos = publish_qos(lockstep)
        # lockstep: the answers held go out when a reader matches (realtime: nothing is held)
        matched = PublisherEventCallbacks(matched=self._on_answer_matched) if lockstep else None
        command_matched = None if self.plans else matched  # with plans the plant reads the plans
        if self.cmd_vel:
            kind, topic = Twist, "cmd_vel"
            self.twist = Twist()
        else:
            kind, topic = Float64MultiArray, "wheel_voltages"
            self.voltage_cdr = three_values_template(VOLTAGE_LABEL)
        # none without the plain command: not on the graph either (a driver's cmd_vel has one source)
        self.command_pub: Publisher | None = None
        if self.plain:
            self.command_pub = node.create_publisher(kind, topic, qos, event_callbacks=command_matched)
        self.diag_pub = node.create_publisher(DiagnosticArray, "diagnostics", qos)
        self.diag_keys: dict[tuple[str, ...], tuple[bytes, ...]] = {}  # the keys of a status, encoded once
        self.held: list[tuple[int | None, Any]] = []  # lockstep: the answers not sent yet (stamp, command or plan)
        self.held_since: float | None = None  # steady time [s] the first of them was held
        self.path_pub = node.create_publisher(Path, "predicted_path", PATH_QOS) if predicted_path else None
        self.path_frame = frame_prefix + ODOM_FRAME
        self.enabled_pub = node.create_publisher(Bool, "controller_enabled", LATCHED_QOS)
        self.plan_pub, self.plan_writer = None, None
        if plan_length is not None:
            self.plan_pub = node.create_publisher(plan_type(command_interface), PLAN_TOPICS[command_interface], qos,
                                                  event_callbacks=matched)
            self.plan_writer = PlanWriter(command_interface, plan_length)
        answer_pub = self.plan_pub if self.plan_pub is not None else self.command_pub  # what the plant reads
        assert answer_pub is not None  # (without plans the plain command is published)
        self.answer_pub: Publisher = answer_pub

    def send_enabled(self, enabled: bool) -> None:
        """Publish the enabled state (latched)."""
        self.enabled_pub.publish(Bool(data=enabled))

    def send(self, outputs: list[Output]) -> None:
        """Publish (log) what a loop answered, in its order."""
        for out in outputs:
            if isinstance(out, Command):
                if not self.plans:
                    self.answer(out.stamp_ns, list(out.values))
                elif self.plain:
                    self.send_command(out.values)
            elif isinstance(out, Diagnostic):
                self.diagnose(out)
            elif isinstance(out, Zero):
                if not self.plans:  # in the answers' order (lockstep: a refused tick's answer)
                    self.answer(None, list(ZERO))
                elif self.plain:  # (with plans the loop sends a plan of zeros too)
                    self.send_command(ZERO)
            elif isinstance(out, Log):
                log_throttled(self.node.get_logger(), out.level.name, out.text, out.throttle_s, out.key)
            elif isinstance(out, PlanOut):
                assert self.plan_writer is not None
                self.answer(out.stamp_ns, self.plan_writer.encode(out.plan))
            elif isinstance(out, PredictedPath):
                self.publish_path(out)
            elif isinstance(out, Resend):
                self.deliver_answers()
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
        assert self.command_pub is not None
        publish_acknowledged(self.node, self.command_pub, msg)

    def answer(self, stamp: int | None, answer: Any) -> None:
        """Publish the answer to the odometry of `stamp` (None: a zero outside the ticks): the command (a list), or
        with plans the plan message; in lockstep held (with those before it) while `_readers_matched` is not met.
        """
        self.held.append((stamp, answer))
        self.deliver_answers()

    def deliver_answers(self) -> None:
        """Publish the answers held, in order, once their readers have matched (else, after a while: a log)."""
        if not self.held:
            return
        if self._readers_matched():
            for _, answer in self.held:
                if self.plans:
                    publish_acknowledged(self.node, self.answer_pub, answer)
                else:
                    self.send_command(answer)
            self.held, self.held_since = [], None
            return
        now = time.monotonic()
        self.held_since = now if self.held_since is None else self.held_since
        if self.readers_needed > 1 and now - self.held_since >= _HOLD_REPORT_AFTER_S:
            warn_throttled(self.node.get_logger(), f"holding {len(self.held)} answer(s) (the first to the odometry "
                           f"of stamp {self.held[0][0]} ns) for {now - self.held_since:.1f} s: "
                           f"{self.answer_pub.topic_name} has matched {self.answer_pub.get_subscription_count()} of "
                           f"its {self.readers_needed} readers (lockstep_command_readers)", 2.0)

    def _readers_matched(self) -> bool:
        """The answers' publisher has its readers: `command_readers` the first time, then one (realtime: always)."""
        matched = self.answer_pub.get_subscription_count()
        if matched < self.readers_needed:
            return False
        self.readers_needed = min(self.readers_needed, 1)
        return True

    def _on_answer_matched(self, info: QoSPublisherMatchedInfo) -> None:
        if info.current_count_change > 0:
            self.deliver_answers()

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
