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
points of one transform each) are read in place by a `ros.cdr.CdrLayout`
(a few microseconds); any other layout is decoded by `ros.cdr.cdr_reader`
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
from robotino_geom_mpc.ros.cdr import MalformedMessage, cdr_reader
from robotino_geom_mpc.ros.decode import InputRejected, odometry_values, preview_of_values, preview_point_values, \
    state_of_odometry
from robotino_geom_mpc.ros.messages import VOLTAGE_LABEL, odometry_layout, preview_layout, three_values_template
from robotino_geom_mpc.ros.parameters import SpecParameters, spec_defaults
from robotino_geom_mpc.ros.qos import CONTROL_QOS, PUBLISH_QOS
from robotino_geom_mpc.ros.spin import monotonic, run_node

__all__ = ["CONTROLLER_SPECS", "ControllerNode", "main"]

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
        self.odom_layout = odometry_layout()
        self.preview_layout = preview_layout(self.control.period_s, self.control.horizon)
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
        self.preview_layout = preview_layout(self.control.period_s, self.control.horizon)
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
