"""The controller node's output side: the command publisher, the lockstep answer bookkeeping, the prediction and
the diagnostics.

`controller_node` computes; this module owns what leaves the node (see the
topics in `controller_node`'s docstring). Publishers use
`ros.qos.publish_qos` (keep-all in lockstep).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray

from robotino_geom_mpc.ros.cdr import CdrTemplate
from robotino_geom_mpc.ros.decode import STAMP_FIELDS
from robotino_geom_mpc.ros.messages import ODOM_FRAME, VOLTAGE_LABEL, three_values_template, yaw_quaternion_zw
from robotino_geom_mpc.ros.qos import publish_acknowledged, publish_qos

__all__ = ["ControllerOutputs", "STATUS_NAME", "TRACKING_KEYS", "diagnostics_cdr"]

STATUS_NAME = "robotino_geom_mpc: controller"
TRACKING_KEYS = ("error_x_m", "error_y_m", "error_theta_rad", "compute_time_ms", "saturated", "infeasible",
                 "preview_stamp_ns", "dt_s")
ZERO = (0.0, 0.0, 0.0)
# the newest prediction only, kept for a late reader (a display); never blocks the loop
PATH_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _path_template(frame: str, horizon: int) -> CdrTemplate:
    """nav_msgs/Path of `horizon` poses in `frame` as a template: header stamp, then per pose its stamp, x, y and the
    yaw quaternion's z, w (`messages.yaw_quaternion_zw`: x = y = 0).
    """
    path = Path(poses=[PoseStamped() for _ in range(horizon)])
    path.header.frame_id = frame
    for pose in path.poses:
        pose.header.frame_id = frame
    return CdrTemplate(path, STAMP_FIELDS + tuple(
        f"poses[{j}].{field}" for j in range(horizon) for field in STAMP_FIELDS + (
            "pose.position.x", "pose.position.y", "pose.orientation.z", "pose.orientation.w")))


_U32 = struct.Struct("<I")
_HEADER = struct.Struct("<4siIIb")  # encapsulation (CDR little endian), stamp, frame_id "" (length 1), its NUL
_ONE_STATUS = _U32.pack(1)
_STATUS_NAME = STATUS_NAME.encode()


def _put_string(out: bytearray, text: bytes) -> None:
    """Append a CDR string (aligned length with the NUL, the bytes, the NUL) to `out` (4 encapsulation bytes first)."""
    out += b"\0" * (-len(out) % 4)
    out += _U32.pack(len(text) + 1)
    out += text
    out += b"\0"


def diagnostics_cdr(stamp: int, level: bytes, message: str, keys: Sequence[bytes], values: Sequence[str]) -> bytes:
    """The serialized DiagnosticArray of the controller's status (frame "", one status named `STATUS_NAME`,
    hardware ``robotino``) with header stamp `stamp` [ns], `level`, `message` and the pairs `keys` (UTF-8) / `values`.

    Plain CDR (XCDR1, little endian) written directly: rclpy's conversion of the 15 key-value pairs cost ~70 us a
    tick, this ~15 us (strings change length, so a `CdrTemplate` cannot serve).
    """
    out = bytearray(_HEADER.pack(b"\0\1\0\0", *divmod(stamp, 1_000_000_000), 1, 0))
    out += b"\0" * (-len(out) % 4)
    out += _ONE_STATUS
    out += level
    _put_string(out, _STATUS_NAME)
    _put_string(out, message.encode())
    _put_string(out, b"robotino")
    out += b"\0" * (-len(out) % 4)
    out += _U32.pack(len(keys))
    for key, value in zip(keys, values):
        _put_string(out, key)
        _put_string(out, value.encode())
    return bytes(out)


class ControllerOutputs:
    """Publishers of the controller node and the last lockstep answer.

    Parameters
    ----------
    node
        The controller node (publishers are created on it).
    lockstep
        Keep-all publishers, and an answer that went out before a reader matched is sent again when one does.
    event_keys
        Keys of the values every diagnostic carries (after the tracking ones).
    event_values
        Their values at a stamp [ns], as strings.
    horizon
        N, the number of poses of ``predicted_path``.
    frame_prefix
        Prefix of the ``odom`` frame of ``predicted_path`` (a namespaced robot's ``robot1/odom``).
    command_interface
        ``voltages``: the command is the wheel voltages [V] on ``wheel_voltages``; ``cmd_vel``: a base_link
        twist (v_x [m/s], v_y [m/s], theta' [rad/s]) on ``cmd_vel`` (geometry_msgs/Twist).
    """

    def __init__(self, node: Node, lockstep: bool, event_keys: Sequence[str],
                 event_values: Callable[[int], list[str]], horizon: int, frame_prefix: str = "",
                 command_interface: str = "voltages") -> None:
        self.node = node
        self.lockstep = lockstep
        self.event_values = event_values
        self.cmd_vel = command_interface == "cmd_vel"
        qos = publish_qos(lockstep)
        matched = PublisherEventCallbacks(matched=self._on_command_matched)
        if self.cmd_vel:
            self.command_pub = node.create_publisher(Twist, "cmd_vel", qos, event_callbacks=matched)
            self.twist = Twist()
        else:
            self.command_pub = node.create_publisher(Float64MultiArray, "wheel_voltages", qos, event_callbacks=matched)
            self.voltage_cdr = three_values_template(VOLTAGE_LABEL)
        self.diag_pub = node.create_publisher(DiagnosticArray, "diagnostics", qos)
        self.diag_keys = tuple(key.encode() for key in (*TRACKING_KEYS, *event_keys))  # with tracking values
        self.event_keys = self.diag_keys[len(TRACKING_KEYS):]  # without
        self.answered: tuple[int, bool, list[float]] | None = None  # stamp, delivered, command
        self.path_pub = node.create_publisher(Path, "predicted_path", PATH_QOS)
        self.path_cdr = _path_template(frame_prefix + ODOM_FRAME, horizon)

    # commands -----------------------------------------------------------------------------------
    def send(self, command: Sequence[float]) -> None:
        """Publish a command: wheel voltages [V], or the base_link twist with ``cmd_vel``."""
        if self.cmd_vel:
            msg = self.twist
            msg.linear.x, msg.linear.y, msg.angular.z = command
        else:
            msg = self.voltage_cdr.pack(*command)
        publish_acknowledged(self.node, self.command_pub, msg)

    def send_zero(self) -> None:
        """Publish zero volts (zero twist)."""
        self.send(ZERO)

    def answer(self, stamp: int, command: list[float]) -> None:
        """Publish the answer to the odometry of `stamp` and remember whether a reader could receive it."""
        delivered = self.command_pub.get_subscription_count() > 0
        self.send(command)
        self.answered = (stamp, delivered, command)

    def deliver_answer(self) -> None:
        """Lockstep: publish the last answer again if it went out before any subscription matched."""
        if self.answered is not None and not self.answered[1] and self.command_pub.get_subscription_count() > 0:
            self.send(self.answered[2])
            self.answered = (self.answered[0], True, self.answered[2])

    def _on_command_matched(self, info: QoSPublisherMatchedInfo) -> None:
        if self.lockstep and info.current_count_change > 0:
            self.deliver_answer()

    # prediction ---------------------------------------------------------------------------------
    def path_wanted(self) -> bool:
        """True while a ``predicted_path`` subscription is matched (the prediction is computed only then)."""
        return self.path_pub.get_subscription_count() > 0

    def publish_path(self, stamp: int, period_ns: int, predicted: np.ndarray) -> None:
        """Publish the predicted poses y(k+1) .. y(k+N) (shape (N, 3), x y theta in odom) of the tick `stamp`.

        The header carries `stamp`, pose j the time `stamp` + j Ts it is predicted for.
        """
        values = [*divmod(stamp, 1_000_000_000)]
        for j, (x, y, theta) in enumerate(predicted.tolist(), start=1):
            values += (*divmod(stamp + j * period_ns, 1_000_000_000), x, y, *yaw_quaternion_zw(theta))
        publish_acknowledged(self.node, self.path_pub, self.path_cdr.pack(*values))

    # diagnostics --------------------------------------------------------------------------------
    def diagnosing(self) -> bool:
        """True while a diagnostics subscription is matched (building the array costs ~70 us a tick)."""
        return self.diag_pub.get_subscription_count() > 0

    def diagnose(self, stamp: int | None, level: bytes, message: str, tracking: list[str] | None = None) -> None:
        """Publish the status (if a subscription is matched); without `tracking` only the event values.

        `stamp` [ns] is the header stamp (None: the node clock).
        """
        if not self.diagnosing():
            return
        if stamp is None:
            stamp = self.node.get_clock().now().nanoseconds
        keys = self.diag_keys if tracking is not None else self.event_keys
        publish_acknowledged(self.node, self.diag_pub, diagnostics_cdr(
            stamp, level, message, keys, (tracking or []) + self.event_values(stamp)))
