"""Controller node: one `MotionController.step` (three MPCs, eq. 56 -> T(theta), eqs. 33-37 -> inverse drive) per odometry.

Topics (relative names)
-----------------------
subscribes ``odom``               nav_msgs/Odometry (pose in ``odom``, twist in ``base_link``)
           ``reference_preview``  trajectory_msgs/MultiDOFJointTrajectory (N + 1 points, see trajectory_node)
publishes  ``wheel_voltages``     std_msgs/Float64MultiArray, 3 values [V], layout label ``wheel_voltage_v``
           ``diagnostics``        diagnostic_msgs/DiagnosticArray, one status ``robotino_geom_mpc: controller``
                                  per tick, header.stamp = the odometry stamp, values: ``error_x_m``,
                                  ``error_y_m``, ``error_theta_rad`` (measured - reference at t_k),
                                  ``compute_time_ms`` (the step), ``saturated``, ``infeasible``,
                                  ``preview_stamp_ns`` (the stamp of the preview used, see below),
                                  ``watchdog`` (waiting, ok, stale_odom, stale_reference), ``rejected``
                                  (inputs refused so far); built and sent only while a subscription
                                  is matched

Both inputs are taken serialized. Bytes laid out as the plant and the
trajectory node send them (frames ``odom``/``base_link``, N + 1 preview
points of one transform each) are read in place by a `common.CdrLayout`
(a few microseconds); any other layout is decoded by `common.cdr_reader`
(rosbags' CDR reader when installed, else rclpy). The wheel_voltages go out
as `CdrTemplate` bytes.

Each odometry message is one control tick: the node computes on its arrival,
which keeps the odometry-to-voltage latency to one step. The preview used is
the one whose stamp equals the odometry stamp in ``lockstep`` (the odometry
waits for it if it comes first), the freshest in ``realtime``, moved in time
from its stamp to the odometry's with its velocities and accelerations
(`core.trajectory.shift_preview`: the trajectory node's timer and the
plant's do not tick in phase, and up to a period apart the reference has
moved v Ts, 3 mm on paper-circle). In lockstep a
repeated odometry stamp (the plant resends a tick) is answered again only if
the first answer could not be delivered (no matched subscriber then), so no
tick is answered twice; such an answer also goes out as soon as a
subscription matches the wheel_voltages publisher.

Time: the controller's time is the stamps of its inputs (the odometry
stamp is the tick); only the watchdog's own zero-volt diagnostics in
realtime read the node clock. It honours ``use_sim_time``, but `run` and
the launch file leave it false in lockstep: a /clock reader would cost a
wake-up per tick (lockstep real-time factor 8.6-10.2 with it, 12.8-14.2
without, measured side by side) and change nothing the node outputs.

A steady-clock watchdog checks the arrival age of the odometry and of the
preview: older than ``odom_timeout_s`` / ``reference_timeout_s`` (after the
first of each arrived) means zero volts (realtime), a throttled warning, the
watchdog state in the diagnostics, and a controller reset when data return.
In lockstep the plant holds the time, so the watchdog only reports.

A NaN/Inf or wrongly sized input is rejected with a throttled warning and
never reaches the output: the tick gets zero volts and an ERROR diagnostic.

Parameters: the robot/control parameters of config/*.yaml (``/**``
section) plus `CONTROLLER_SPECS`; a change rebuilds (and resets) the controller.
"""

from __future__ import annotations

import math

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.core.controller import ControllerInputError, MotionController, odometry_state_floats
from robotino_geom_mpc.core.params import ALL_SPECS, ParamSpec
from robotino_geom_mpc.core.trajectory import shift_preview
from robotino_geom_mpc.nodes.common import (
    CONTROL_QOS,
    PUBLISH_QOS,
    VOLTAGE_LABEL,
    CdrLayout,
    MalformedMessage,
    SpecParameters,
    cdr_reader,
    monotonic,
    run_node,
    spec_defaults,
    three_values_template,
    unwrap_near,
    yaw_of,
)
from robotino_geom_mpc.nodes.trajectory_node import preview_skeleton

__all__ = ["CONTROLLER_SPECS", "ControllerNode", "odometry_values", "state_of_odometry", "odometry_state",
           "preview_point_values", "preview_of_values", "preview_arrays", "main"]

STATUS_NAME = "robotino_geom_mpc: controller"
# the general decoders (field names are all `odometry_values` and `preview_point_values` use, so either one fits)
_read_odom = cdr_reader(Odometry, "nav_msgs/msg/Odometry")
_read_preview = cdr_reader(MultiDOFJointTrajectory, "trajectory_msgs/msg/MultiDOFJointTrajectory")

CONTROLLER_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("mode", str, "realtime: freshest preview, watchdog outputs zero volts; lockstep: preview of the same stamp",
              choices=("realtime", "lockstep")),
    ParamSpec("odom_timeout_s", float, "Odometry older than this is stale (zero volts)", "s", 0.0, 60.0, True),
    ParamSpec("reference_timeout_s", float, "Reference preview older than this is stale (zero volts)", "s", 0.0, 60.0,
              True),
)
_DEFAULTS = {"mode": "realtime", "odom_timeout_s": 0.1, "reference_timeout_s": 0.1}


class InputRejected(ValueError):
    """An odometry or preview message with non-finite values or the wrong size."""


_STAMP = ("header.stamp.sec", "header.stamp.nanosec")
_ODOM_PATHS = _STAMP + tuple("pose.pose." + f for f in (
    "position.x", "position.y", "orientation.x", "orientation.y", "orientation.z", "orientation.w")) + (
    "twist.twist.linear.x", "twist.twist.linear.y", "twist.twist.angular.z")
# per preview point: pose (x, y, yaw quaternion), then velocity and acceleration (x, y, theta)
_POINT_FIELDS = tuple(f"transforms[0].{f}" for f in (
    "translation.x", "translation.y", "rotation.x", "rotation.y", "rotation.z", "rotation.w")) + tuple(
    f"{kind}[0].{f}" for kind in ("velocities", "accelerations") for f in ("linear.x", "linear.y", "angular.z"))
_POINT_SIZE = len(_POINT_FIELDS)


def _odom_layout() -> CdrLayout:
    """The odometry the plant sends (REP-105 frames), read in place."""
    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    return CdrLayout(msg, _ODOM_PATHS)


def _preview_layout(period_s: float, horizon: int) -> CdrLayout:
    """The preview the trajectory node sends (`trajectory_node.preview_skeleton`), read in place."""
    return CdrLayout(preview_skeleton(period_s, horizon), _STAMP + tuple(
        f"points[{j}].{f}" for j in range(horizon + 1) for f in _POINT_FIELDS))


def odometry_values(msg: Odometry) -> tuple:
    """(stamp sec, stamp nanosec, x, y, q_x, q_y, q_z, q_w, v_x, v_y, omega) of a decoded odometry message."""
    p, q, tw = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, p.x, p.y, q.x, q.y, q.z, q.w,
            tw.linear.x, tw.linear.y, tw.angular.z)


def state_of_odometry(values: tuple, previous_theta: float) -> np.ndarray:
    """Body state X = (x, x', y, y', theta, theta') (eq. 2) of `odometry_values` (without the stamp).

    theta is unwrapped next to `previous_theta`; the base_link twist is
    rotated into ``odom`` by the measured heading (`core.controller.odometry_state_floats`).

    Raises
    ------
    InputRejected
        If any value is not finite.
    """
    x, y, qx, qy, qz, qw, vx, vy, omega = values
    if not math.isfinite(sum(values)):
        raise InputRejected("odom contains non-finite values")
    theta = unwrap_near(yaw_of(qx, qy, qz, qw), previous_theta)
    return np.array(odometry_state_floats((x, y, theta), (vx, vy, omega)))


def odometry_state(msg: Odometry, previous_theta: float) -> np.ndarray:
    """`state_of_odometry` of a decoded odometry message."""
    return state_of_odometry(odometry_values(msg)[2:], previous_theta)


def preview_point_values(msg: MultiDOFJointTrajectory, horizon: int) -> tuple:
    """Per point 0..N of a decoded preview: x, y, q_x, q_y, q_z, q_w, velocity and acceleration (x, y, theta), flat.

    A point without velocities or accelerations gets zeros there (its pose is then used as it is).

    Raises
    ------
    InputRejected
        If the message does not have N + 1 points with one transform (and at most one velocity and
        acceleration) each.
    """
    if len(msg.points) != horizon + 1:
        raise InputRejected(f"reference_preview has {len(msg.points)} points, need N + 1 = {horizon + 1}")
    out = []
    for j, point in enumerate(msg.points):
        if len(point.transforms) != 1 or len(point.velocities) > 1 or len(point.accelerations) > 1:
            raise InputRejected(f"reference_preview point {j} has {len(point.transforms)} transforms, "
                                f"{len(point.velocities)} velocities, {len(point.accelerations)} accelerations; "
                                "need 1, at most 1, at most 1")
        tr, q = point.transforms[0].translation, point.transforms[0].rotation
        out += (tr.x, tr.y, q.x, q.y, q.z, q.w)
        for twists in (point.velocities, point.accelerations):
            out += (twists[0].linear.x, twists[0].linear.y, twists[0].angular.z) if twists else (0.0, 0.0, 0.0)
    return tuple(out)


def preview_of_values(values: tuple, theta_near: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (x, y, theta), velocities and accelerations of `preview_point_values`, each (N + 1, 3).

    Theta is unwrapped from `theta_near`.

    Raises
    ------
    InputRejected
        If a value is not finite.
    """
    if not math.isfinite(sum(values)):
        raise InputRejected("reference_preview contains non-finite values")
    points = np.array(values, dtype=float).reshape(-1, _POINT_SIZE)
    positions = np.empty((len(points), 3))
    theta = theta_near
    for j, (x, y, qx, qy, qz, qw) in enumerate(points[:, :6].tolist()):
        theta = unwrap_near(yaw_of(qx, qy, qz, qw), theta)
        positions[j] = (x, y, theta)
    return positions, points[:, 6:9], points[:, 9:12]


def preview_arrays(msg: MultiDOFJointTrajectory, horizon: int,
                   theta_near: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`preview_of_values` of a decoded preview (N + 1 points).

    Raises
    ------
    InputRejected
        If the message does not have the points `preview_point_values` needs, or holds non-finite values.
    """
    return preview_of_values(preview_point_values(msg, horizon), theta_near)


_TRACKING_KEYS = ("error_x_m", "error_y_m", "error_theta_rad", "compute_time_ms", "saturated", "infeasible",
                  "preview_stamp_ns")
_EVENT_KEYS = ("watchdog", "rejected")


def _diagnostics_message(keys: tuple[str, ...]) -> DiagnosticArray:
    """A DiagnosticArray of one controller status with these keys (values set per publish)."""
    status = DiagnosticStatus(name=STATUS_NAME, hardware_id="robotino", values=[KeyValue(key=k) for k in keys])
    return DiagnosticArray(status=[status])


class ControllerNode(Node):
    """The controller node (see the module docstring for its interface)."""

    def __init__(self) -> None:
        super().__init__("robotino_controller")
        self.params = SpecParameters(self, ALL_SPECS + CONTROLLER_SPECS, {**spec_defaults(), **_DEFAULTS},
                                     self._on_params, fixed=("mode",))
        self.robot, self.control = self.params.robot_control()
        self.controller = MotionController(self.robot, self.control)
        self.lockstep = self.params["mode"] == "lockstep"

        self.voltage_pub = self.create_publisher(
            Float64MultiArray, "wheel_voltages", PUBLISH_QOS,
            event_callbacks=PublisherEventCallbacks(matched=self._on_voltage_matched),
        )
        self.voltage_cdr = three_values_template(VOLTAGE_LABEL)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", PUBLISH_QOS)
        # built once, values rewritten per tick (a third of the cost of building the message anew)
        self.diag_tracking = _diagnostics_message(_TRACKING_KEYS + _EVENT_KEYS)
        self.diag_event = _diagnostics_message(_EVENT_KEYS)
        self.odom_layout = _odom_layout()
        self.preview_layout = _preview_layout(self.control.period_s, self.control.horizon)
        self.odom_sub = self.create_subscription(Odometry, "odom", self._on_odom, CONTROL_QOS, raw=True)
        self.preview_sub = self.create_subscription(
            MultiDOFJointTrajectory, "reference_preview", self._on_preview, CONTROL_QOS, raw=True
        )

        self.theta = 0.0  # last measured (continuous) yaw
        self.previews: dict[int, np.ndarray] = {}  # stamp [ns] -> (N + 1, 3)
        # realtime: stamp [ns], positions, velocities, accelerations of the freshest preview
        self.latest_preview: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.pending: tuple[int, np.ndarray] | None = None  # lockstep: odometry waiting for its preview
        self.answered: tuple[int, bool, list[float]] | None = None  # stamp, delivered, voltages
        self.odom_time = self.preview_time = None  # steady arrival times
        self.watchdog_state = "waiting"
        self.rejected = 0
        timeout = min(self.params["odom_timeout_s"], self.params["reference_timeout_s"])
        self.watchdog = self.create_timer(timeout / 2, self._check_watchdog,
                                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"controller ready ({self.params['mode']}, mode {self.control.mode}, "
                               f"N = {self.control.horizon}, Ts = {self.control.period_s:g} s)")

    def _on_params(self, changed: dict) -> None:
        self.robot, self.control = self.params.robot_control()
        self.controller = MotionController(self.robot, self.control)
        self.preview_layout = _preview_layout(self.control.period_s, self.control.horizon)
        self.previews.clear()
        self.latest_preview = None

    # inputs -------------------------------------------------------------------------------------
    def _reject(self, stamp: int, reason: str) -> None:
        self.rejected += 1
        self.get_logger().warn(f"rejected input: {reason}; zero volts", throttle_duration_sec=1.0)
        self.voltage_pub.publish(self.voltage_cdr.pack(0.0, 0.0, 0.0))
        self._diagnose(stamp, DiagnosticStatus.ERROR, f"rejected input: {reason}", None, None, None)

    def _on_preview(self, data: bytes) -> None:
        try:
            values = self.preview_layout.read(data)
            if values is None:
                msg = _read_preview(data)
                header = msg.header
                values = (header.stamp.sec, header.stamp.nanosec, *preview_point_values(msg, self.control.horizon))
            positions, velocities, accelerations = preview_of_values(values[2:], self.theta)
        except (MalformedMessage, InputRejected) as exc:
            self.rejected += 1
            self.get_logger().warn(f"rejected reference_preview: {exc}", throttle_duration_sec=1.0)
            return
        self.preview_time = monotonic()
        stamp = values[0] * 1_000_000_000 + values[1]
        if not self.lockstep:
            self.latest_preview = (stamp, positions, velocities, accelerations)
            return
        self.previews[stamp] = positions
        if self.pending is not None and self.pending[0] == stamp:
            odom_stamp, X = self.pending
            self.pending = None
            self._control(odom_stamp, X, positions, stamp)

    def _on_odom(self, data: bytes) -> None:
        try:
            values = self.odom_layout.read(data)
            if values is None:
                values = odometry_values(_read_odom(data))
        except MalformedMessage as exc:
            self.rejected += 1
            self.get_logger().warn(f"rejected malformed odom: {exc!r}", throttle_duration_sec=1.0)
            return
        stamp = values[0] * 1_000_000_000 + values[1]
        try:
            X = state_of_odometry(values[2:], self.theta)
        except InputRejected as exc:
            self._reject(stamp, str(exc))
            return
        self.odom_time = monotonic()
        if self.answered is not None and self.answered[0] == stamp and self.lockstep:
            self._deliver_answer()
            return
        self.theta = X[4]
        if self.lockstep:
            for old in [s for s in self.previews if s < stamp]:
                del self.previews[old]
            positions, preview_stamp = self.previews.get(stamp), stamp
            if positions is None:
                self.pending = (stamp, X)
                return
        else:
            if self.latest_preview is None or self.odom_time - self.preview_time > self.params["reference_timeout_s"]:
                return  # stale reference: the watchdog outputs zero volts
            preview_stamp, positions, velocities, accelerations = self.latest_preview
            positions = shift_preview(positions, velocities, accelerations, (stamp - preview_stamp) * 1e-9)
        self._control(stamp, X, positions, preview_stamp)

    def _deliver_answer(self) -> None:
        """Lockstep: publish the last answer again if it went out before any subscription matched."""
        if self.answered is not None and not self.answered[1] and self.voltage_pub.get_subscription_count() > 0:
            self.voltage_pub.publish(self.voltage_cdr.pack(*self.answered[2]))
            self.answered = (self.answered[0], True, self.answered[2])

    def _on_voltage_matched(self, info: QoSPublisherMatchedInfo) -> None:
        if self.lockstep and info.current_count_change > 0:
            self._deliver_answer()

    # control ------------------------------------------------------------------------------------
    def _control(self, stamp: int, X: np.ndarray, positions: np.ndarray, preview_stamp: int) -> None:
        """One step on the odometry of `stamp` and the preview of `preview_stamp` (its `positions`, moved to `stamp`)."""
        try:
            out = self.controller.step(X, positions[1:])
        except ControllerInputError as exc:
            self._reject(stamp, str(exc))
            return
        compute_s = out.compute_time_s
        voltages = [float(v) for v in out.voltages]
        delivered = self.voltage_pub.get_subscription_count() > 0
        self.voltage_pub.publish(self.voltage_cdr.pack(*voltages))
        self.answered = (stamp, delivered, voltages)
        error = X[[0, 2, 4]] - positions[0]
        flags = (bool(out.saturated), bool(out.infeasible))
        level = DiagnosticStatus.WARN if any(flags) else DiagnosticStatus.OK
        self._diagnose(stamp, level, "tracking", error, compute_s, flags, preview_stamp)

    def _diagnose(self, stamp: int, level, message: str, error, compute_s, flags, preview_stamp=None) -> None:
        """Publish the status (if a subscription is matched); `error` None: only the watchdog state and rejections."""
        if not self.diag_pub.get_subscription_count():
            return  # building and serializing the array costs ~70 us a tick
        msg = self.diag_tracking if error is not None else self.diag_event
        status = msg.status[0]
        status.level, status.message = level, message
        text = []
        if error is not None:
            text += [f"{e:.9g}" for e in error]
            text += [f"{compute_s * 1e3:.4f}", str(flags[0]).lower(), str(flags[1]).lower(), str(preview_stamp)]
        text += [self.watchdog_state, str(self.rejected)]
        for pair, value in zip(status.values, text):
            pair.value = value
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        self.diag_pub.publish(msg)

    # watchdog -----------------------------------------------------------------------------------
    def _check_watchdog(self) -> None:
        if self.odom_time is None or self.preview_time is None:
            return
        now = monotonic()
        if now - self.odom_time > self.params["odom_timeout_s"]:
            state = "stale_odom"
        elif now - self.preview_time > self.params["reference_timeout_s"]:
            state = "stale_reference"
        else:
            state = "ok"
        previous, self.watchdog_state = self.watchdog_state, state
        if state == "ok" or self.lockstep:  # lockstep: the plant holds the time; report only
            return
        if previous == "ok":
            self.controller.reset()  # u(k-1) of the Delta-u form is stale when data return
        self.get_logger().warn(f"watchdog: {state.replace('_', ' ')}; zero volts", throttle_duration_sec=1.0)
        self.voltage_pub.publish(self.voltage_cdr.pack(0.0, 0.0, 0.0))
        self._diagnose(self.get_clock().now().nanoseconds, DiagnosticStatus.WARN, f"watchdog: {state}", None, None,
                       None)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc controller_node``."""
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
