"""Controller node: one `MotionController.step` (three MPCs, eq. 56 -> T(theta), eqs. 33-37 -> inverse drive) a tick.

Topics (relative names)
-----------------------
subscribes ``odom``               nav_msgs/Odometry (pose in ``odom``, twist in ``base_link``)
           ``reference_preview``  trajectory_msgs/MultiDOFJointTrajectory (N + 1 points, see trajectory_node)
publishes  ``wheel_voltages``     std_msgs/Float64MultiArray, 3 values [V], layout label ``wheel_voltage_v``
                                  (``command_interface`` voltages, the default), or
           ``cmd_vel``            geometry_msgs/Twist in base_link (``command_interface`` cmd_vel): the MPC's
                                  velocity at the next period (`MotionController.next_velocity`); every
                                  "zero volts" below is then a zero twist
           ``diagnostics``        diagnostic_msgs/DiagnosticArray, one status ``robotino_geom_mpc: controller``
                                  per tick and per event, header.stamp = the odometry stamp (events without
                                  one: the node clock). Per tick (message ``tracking``): ``error_x_m``,
                                  ``error_y_m``, ``error_theta_rad`` (measured - reference at t_k, the
                                  reference without the blend), ``compute_time_ms``, ``saturated``,
                                  ``infeasible``, ``preview_stamp_ns`` (the preview used), ``dt_s`` (the
                                  interval passed to the step). Always: ``watchdog`` (waiting, ok,
                                  stale_odom, stale_reference), ``rejected`` (refusals so far),
                                  ``last_refusal`` (its reason key, ``none``), ``dropped_duplicate``,
                                  ``dropped_old``, ``blend_remaining_s``, ``blend_engagements``. Built and
                                  sent only while a subscription is matched.
           ``predicted_path``     nav_msgs/Path in ``<frame_prefix>odom``: the MPCs' y(k+1) .. y(k+N) (eq. 50
                                  under the optimal increments of eq. 56), pose j stamped t_k + j Ts; computed
                                  and sent only while a subscription is matched.
services   ``~/enable``           std_srvs/SetBool. Disabled: zero output every tick (diagnostic message
                                  ``disabled``; realtime: on every odometry, with or without a reference), the
                                  controller holds its state; enabled again: bumpless restart. ``start_enabled``
                                  false starts the node disabled (the first enable is its bumpless start).
publishes  ``controller_enabled`` std_msgs/Bool, `LATCHED_QOS` (reliable, transient local, depth 1): the enabled
                                  state, at start and on every change (a trajectory node with
                                  ``start_on_enable`` starts its reference when it turns true).

Publishers: `controller_outputs.ControllerOutputs`. Inputs are read in
place by a `ros.cdr.CdrLayout` (any other layout: `ros.cdr.cdr_reader`).

Each odometry message is one control tick: the node computes on its arrival. The preview used is the one
whose stamp equals the odometry stamp in ``lockstep`` (the odometry waits for it if it comes first), the
freshest in ``realtime``, moved in time to the odometry's stamp with its velocities and accelerations
(`reference.trajectories.shift_preview`). The step gets ``dt_s`` = the interval between the stamps of this
odometry and of the last one used (None when it is exactly one period, and after a (re)start).

Time: the stamps of the inputs; in realtime the node clock (``use_sim_time`` honoured) is read once per
input to check its stamp. The watchdog counts the node clock under ``use_sim_time`` (read at start),
steady time otherwise. Frames: a preview not in ``<frame_prefix>odom`` is refused (reason ``frame``).

Bad input, stale data and the stop: `controller_inputs` (zero volts and a diagnostic naming the reason).
Plans (``plans``, an off-board controller over a network): `controller_plans` (delay-compensated plans on
``wheel_voltage_plan`` / ``cmd_vel_plan``, the robot's ``command_applied`` read, the link in the diagnostics). In
lockstep the odometries of a tick are answered in arrival order, each with the preview of its stamp.

Bumpless (re)start (`control.blend.BlendEngagement`): at the first tick (except tick t = 0 of a lockstep
run, where robot and reference start together as in `simulate`), after stale data or ``~/enable`` turned
on again, at a preview whose reference jumped (more than ``reference_jump_m`` / ``reference_jump_rad``
from the previous preview moved to its stamp, e.g. a restarted trajectory node) and after a parameter
change, the controller is reset (u(k-1) = 0, pose filter restarted) and a C^3 offset o(t) is added to the
preview, taking the reference from the measured pose and velocity to itself within the shortest time
whose offset acceleration stays within ``blend_acceleration_mps2`` / ``blend_acceleration_radps2``.

Parameters: the robot/control parameters of config/*.yaml (``/**`` section) plus
`controller_inputs.CONTROLLER_SPECS`. A set is refused with the reason when the values cannot run
(`controller_inputs.closed_loop_problem`: a timeout under two periods, an unstable nominal closed loop, a model
the controller cannot be built on; also at start: exit status 2) and for ``mode``, ``frame_prefix``,
``command_interface``, ``control.period_s`` and ``control.horizon`` (the last two must agree with the trajectory
node: restart instead); any other accepted change of a robot/control parameter rebuilds the controller with a
bumpless restart.
"""

from __future__ import annotations

import traceback

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import Bool
from std_srvs.srv import SetBool
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.control.blend import BlendEngagement, BlendError
from robotino_geom_mpc.control.motion_controller import (MAX_POSITION_M, ControllerInputError, MotionController,
                                                         step_interval)
from robotino_geom_mpc.params.specs import ALL_SPECS
from robotino_geom_mpc.reference.trajectories import shift_preview
from robotino_geom_mpc.description.urdf import DescriptionError, check_frame_prefix
from robotino_geom_mpc.nodes.chain_control import CHAIN_NODE_DEFAULTS, CHAIN_NODE_SPECS, chain_control
from robotino_geom_mpc.nodes.controller_inputs import CONTROLLER_DEFAULTS, CONTROLLER_SPECS, FIXED_WHILE_RUNNING, \
    InputCounters, closed_loop_problem, reference_jump
from robotino_geom_mpc.nodes.controller_outputs import ControllerOutputs
from robotino_geom_mpc.nodes.controller_plans import LINK_KEYS, ControllerPlans
from robotino_geom_mpc.nodes.controller_watchdog import ControllerWatchdog
from robotino_geom_mpc.ros.cdr import MalformedMessage, cdr_reader
from robotino_geom_mpc.ros.decode import InputRejected, odometry_values, preview_of_values, preview_point_values, \
    stamp_problem, state_of_odometry, time_ns
from robotino_geom_mpc.ros.messages import ODOM_FRAME, odometry_layout, preview_layout
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters, spec_defaults
from robotino_geom_mpc.ros.plans import REPORT_WINDOW_S
from robotino_geom_mpc.ros.qos import CONTROL_QOS, LATCHED_QOS, LOCKSTEP_PUBLISH_QOS
from robotino_geom_mpc.ros.spin import monotonic, run_node
from robotino_geom_mpc.ros.throttle import error_throttled, warn_throttled

__all__ = ["CONTROLLER_SPECS", "ControllerNode", "main"]

# the general decoders (field names are all `odometry_values` and `preview_point_values` use, so either one fits)
_read_odom = cdr_reader(Odometry, "nav_msgs/msg/Odometry")
_read_preview = cdr_reader(MultiDOFJointTrajectory, "trajectory_msgs/msg/MultiDOFJointTrajectory")

_EVENT_KEYS = ("watchdog", *InputCounters.KEYS, "blend_remaining_s", "blend_engagements")
_ROBOT_CONTROL = frozenset(s.name for s in ALL_SPECS)


class ControllerNode(ControllerWatchdog, Node):
    """The controller node (see the module docstring for its interface)."""

    def __init__(self) -> None:
        super().__init__("robotino_controller")
        defaults = {**spec_defaults(), **CONTROLLER_DEFAULTS, **CHAIN_NODE_DEFAULTS}
        self.params = SpecParameters(self, ALL_SPECS + CONTROLLER_SPECS + CHAIN_NODE_SPECS, defaults, self._on_params,
                                     fixed=(*FIXED_WHILE_RUNNING, *CHAIN_NODE_DEFAULTS), check=closed_loop_problem)
        self.robot, self.control = self.params.robot_control()
        self.controller = MotionController(self.robot, self.control)
        self.lockstep = self.params["mode"] == "lockstep"
        self.period_ns = int(round(self.control.period_s * 1e9))
        self._read_limits()

        try:
            prefix = check_frame_prefix(self.params["frame_prefix"])
        except DescriptionError as exc:
            raise NodeStartError(f"parameter 'frame_prefix': {exc}") from None
        self.plans = ControllerPlans(self, self.robot, self.control, self.params["command_interface"], self.lockstep,
                                     REPORT_WINDOW_S) if self.params["plans"] else None
        self.preview_points = self.control.horizon if self.plans is None else self.plans.preview_length
        self.outputs = ControllerOutputs(self, self.lockstep, _EVENT_KEYS + (LINK_KEYS if self.plans else ()),
                                         self._event_values, self.control.horizon, prefix,
                                         self.params["command_interface"])
        self.odom_frame = prefix + ODOM_FRAME  # the frame of the previews it takes
        self.chain = chain_control(self)  # chain.active: control through the driver chain (`chain_control`)
        self.enabled = self.params["start_enabled"]
        self.enable_srv = self.create_service(SetBool, "~/enable", self._on_enable)
        self.enabled_pub = self.create_publisher(Bool, "controller_enabled", LATCHED_QOS)
        self.enabled_pub.publish(Bool(data=self.enabled))
        self.odom_layout = odometry_layout(prefix)  # other frames are read by the general decoder
        self.preview_layout = preview_layout(self.control.period_s, self.preview_points, prefix)
        # lockstep plans: the previews of the ticks before an odometry's late delivery are all kept
        qos = LOCKSTEP_PUBLISH_QOS if self.plans is not None and self.lockstep else CONTROL_QOS
        self.odom_sub = self.create_subscription(Odometry, "odom", self._on_odom, qos, raw=True)
        self.preview_sub = self.create_subscription(MultiDOFJointTrajectory, "reference_preview", self._on_preview,
                                                    qos, raw=True)

        self.theta = 0.0  # last measured (continuous) yaw
        # lockstep: stamp [ns] -> (positions, velocities, accelerations), each (N + 1, 3)
        self.previews: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        # the newest preview: stamp [ns], positions, velocities, accelerations (realtime: the one used)
        self.latest_preview: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.pending: tuple[int, np.ndarray, list] | None = None  # lockstep: the first odometry waiting for its preview
        # lockstep: odometries in arrival order, with that one first, each with the reports held for it (plans)
        self.waiting: list[tuple[int, np.ndarray, list]] = []
        if self.plans is not None and self.lockstep:
            self.plans.hold_into = lambda: self.waiting[-1][2] if self.waiting else None
        self.pending_since = 0.0
        self.last_odom_ns: int | None = None  # stamp of the last odometry used (dt, duplicates, order)
        # the watchdog's clock, read at start: the node clock under use_sim_time (a slow simulation is slow, not
        # stale), else steady time
        self.sim_time = bool(self.get_parameter("use_sim_time").value)
        self._watch_now = (lambda: self.get_clock().now().nanoseconds * 1e-9) if self.sim_time else monotonic
        self.odom_time = self.preview_time = None  # arrival times of accepted inputs (`_watch_now`)
        self.start_time = self._watch_now()
        self.watchdog_state = "waiting"
        self.counters = InputCounters()
        self.blend = BlendEngagement(self.control.period_s, self.preview_points)
        self.watchdog = self._start_watchdog()
        disabled = "" if self.enabled else \
            f"; disabled (zero output) until {self.resolve_service_name(self.enable_srv.srv_name)} true"
        self.get_logger().info(f"controller ready ({self.params['mode']}, mode {self.control.mode}, "
                               f"N = {self.control.horizon}, Ts = {self.control.period_s:g} s){disabled}")

    # parameters ---------------------------------------------------------------------------------
    def _read_limits(self) -> None:
        """The node's own parameters as attributes (read per tick)."""
        p = self.params
        self.odom_timeout_ns = int(p["odom_timeout_s"] * 1e9)
        self.reference_timeout_ns = int(p["reference_timeout_s"] * 1e9)
        self.future_ns = int(p["future_tolerance_s"] * 1e9)
        self.tolerances = (p["quaternion_norm_tolerance"], p["tilt_tolerance_rad"])
        self.jump_limits = (p["reference_jump_m"], p["reference_jump_rad"])
        self.blend_limits = (p["blend_acceleration_mps2"], p["blend_acceleration_radps2"])

    def _on_params(self, changed: dict) -> None:
        self._read_limits()
        if {"odom_timeout_s", "reference_timeout_s"} & changed.keys():
            self.destroy_timer(self.watchdog)
            self.watchdog = self._start_watchdog()
        if _ROBOT_CONTROL & changed.keys():
            self.robot, self.control = self.params.robot_control()
            self.controller = MotionController(self.robot, self.control)
            if self.plans is not None:
                self.plans.rebuild(self.robot, self.control)
            self.blend.request("parameters")  # the new controller starts from u(k-1) = 0: blend from the state
            self.get_logger().info(f"parameters {sorted(changed)} changed: controller rebuilt, bumpless restart")

    def on_stop(self) -> None:
        """Realtime: leave the drives at zero volts (a base at zero twist) as the node stops (`ros.spin.run_node`).

        Lockstep does not: the plant holds the time and pairs every command with its tick.
        """
        if not self.lockstep:
            self.outputs.send_zero()

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """~/enable: false holds (zero output every tick, the controller untouched); true re-engages bumplessly.

        A node started disabled (``start_enabled`` false) that has never tracked keeps its pending start
        engagement (bumpless too; at t = 0 of a lockstep run exactly as `simulate` starts).
        """
        if request.data != self.enabled:
            self.enabled = request.data
            if self.enabled and self.blend.reason != "start":
                self.blend.request("enable")  # u(k-1) = 0 (the robot held), blend from the measured state
            self.enabled_pub.publish(Bool(data=self.enabled))
            self.get_logger().info("enabled: tracking resumes bumplessly" if self.enabled else
                                   "disabled: zero output, holding")
        response.success, response.message = True, "enabled" if self.enabled else "disabled"
        return response

    # inputs -------------------------------------------------------------------------------------
    def _reject(self, stamp: int | None, what: str, reason: str, message: str) -> None:
        """A refused input: counted, logged, zero volts, an ERROR diagnostic naming the reason."""
        self.counters.refuse(reason)
        warn_throttled(self.get_logger(), f"refused {what}: {message}; zero volts", 1.0)
        self.outputs.send_zero()
        self.outputs.diagnose(stamp, DiagnosticStatus.ERROR, f"refused {what} ({reason}): {message}")

    def _drop(self, stamp: int, what: str, reason: str) -> None:
        """A dropped input (duplicate or older stamp than the last used): counted, logged, a WARN diagnostic."""
        self.counters.drop(reason)
        warn_throttled(self.get_logger(), f"dropped {what} of stamp {stamp} ns: {reason}", 1.0)
        self.outputs.diagnose(stamp, DiagnosticStatus.WARN, f"dropped {what} ({reason})")

    def _now_ns(self) -> int | None:
        """The node clock (realtime), None in lockstep (stamps are simulated time there)."""
        return None if self.lockstep else self.get_clock().now().nanoseconds

    def _on_preview(self, data: bytes) -> None:
        stamp = None
        try:
            values = self.preview_layout.read(data)
            if values is None:
                msg = _read_preview(data)
                sec, nanosec = msg.header.stamp.sec, msg.header.stamp.nanosec
                stamp = time_ns(sec, nanosec)  # first: a wrongly sized preview is refused for its tick
                if msg.header.frame_id != self.odom_frame:  # another robot's odom, or a prefix mismatch
                    raise InputRejected(f"reference_preview is in frame '{msg.header.frame_id}', not in the "
                                        f"controller's '{self.odom_frame}'", "frame")
                values = (sec, nanosec, *preview_point_values(msg, self.preview_points))
            else:
                stamp = time_ns(values[0], values[1])
            latest = self.latest_preview
            if not self.lockstep:  # lockstep: the trajectory resends previews on purpose, keyed by stamp
                problem = stamp_problem(stamp, None if latest is None else latest[0], self._now_ns(),
                                        self.reference_timeout_ns, self.future_ns)
                if problem in ("duplicate", "old"):
                    self._drop(stamp, "reference_preview", problem)
                    return
                if problem is not None:
                    raise InputRejected(f"stamp {stamp} ns is {problem}", problem)
            arrays = preview_of_values(values[2:], self.theta, *self.tolerances)
            if np.abs(arrays[0][:, :2]).max() > MAX_POSITION_M:
                raise InputRejected(f"reference_preview has a position beyond {MAX_POSITION_M:g} m", "implausible")
        except (MalformedMessage, InputRejected) as exc:
            self._refuse_preview(stamp, getattr(exc, "reason", "malformed"), str(exc))
            return
        self.preview_time = self._watch_now()
        if latest is None or stamp > latest[0]:
            jump = reference_jump(latest, stamp, arrays[0][0], *self.jump_limits)
            if jump is not None:
                self.blend.jump_ns = stamp
                warn_throttled(self.get_logger(), f"{jump}: bumpless restart", 1.0)
            self.latest_preview = (stamp, *arrays)
        if not self.lockstep:
            return
        self.previews[stamp] = arrays
        self._drain()

    def _drain(self) -> None:
        """Lockstep: step the waiting odometries in arrival order while the preview of the first is there (over
        a link several arrive at one tick, each answered in turn).
        """
        while self.waiting:
            stamp, X, held = self.waiting[0]
            if self.last_odom_ns is not None and stamp <= self.last_odom_ns:  # overtaken while it waited
                del self.waiting[0]
                self._drop(stamp, "odom", "old")
                if held:  # the reports that came after it (only with plans)
                    self.plans.take(held)
                continue
            arrays = self.previews.get(stamp)
            if arrays is None:
                break
            del self.waiting[0]
            self.pending_since = self._watch_now()
            if isinstance(arrays, InputRejected):
                self._reject(stamp, "odom", f"preview_{arrays.reason}", f"the preview of this tick was refused: "
                             f"{arrays}")
            else:
                self._control(stamp, X, *arrays, stamp)
            if held:
                self.plans.take(held)
            for old in [s for s in self.previews if s < stamp]:
                del self.previews[old]
        self.pending = self.waiting[0] if self.waiting else None

    def _refuse_preview(self, stamp: int | None, reason: str, message: str) -> None:
        """Realtime: zero volts now; lockstep: for the tick of its stamp (of none if unknown: only counted)."""
        if not self.lockstep:
            self._reject(stamp, "reference_preview", reason, message)
            return
        self.counters.refuse(reason)
        warn_throttled(self.get_logger(), f"refused reference_preview: {message}", 1.0)
        if stamp is None:
            return
        self.previews[stamp] = InputRejected(message, reason)
        self._drain()

    def _on_odom(self, data: bytes) -> None:
        try:
            values = self.odom_layout.read(data)
            if values is None:
                values = odometry_values(_read_odom(data))
            stamp = time_ns(values[0], values[1])
        except (MalformedMessage, InputRejected) as exc:
            self._reject(None, "odom", getattr(exc, "reason", "malformed"), str(exc))
            return
        problem = stamp_problem(stamp, self.last_odom_ns, self._now_ns(), self.odom_timeout_ns, self.future_ns)
        problem = None if self.chain is not None and problem in ("duplicate", "stale") else problem  # `chain_control`
        if problem is not None:
            if problem == "duplicate" and self.lockstep:
                self.outputs.deliver_answer()  # the plant resent a tick: answer again only if undelivered
            if problem in ("duplicate", "old"):
                self._drop(stamp, "odom", problem)
            else:
                self._reject(stamp, "odom", problem, f"stamp {stamp} ns is {problem}")
            return
        try:
            X = state_of_odometry(values[2:], self.theta, *self.tolerances)
            problem = self.controller.state_problem(X)
            if problem is not None:
                raise InputRejected(f"odom {problem}", "implausible")
        except InputRejected as exc:
            self._reject(stamp, "odom", exc.reason, str(exc))
            return
        self.odom_time = self._watch_now()
        self.theta = X[4]
        if not self.enabled and not self.lockstep:  # lockstep: each tick answered with the preview of its stamp
            self._hold(stamp)
            return
        if self.lockstep:
            if all(waiting != stamp for waiting, _, _ in self.waiting):
                if not self.waiting:
                    self.pending_since = self.odom_time
                self.waiting.append((stamp, X, []))
            self._drain()
            return
        if self.latest_preview is None or self.odom_time - self.preview_time > self.params["reference_timeout_s"]:
            return  # stale reference: the watchdog outputs zero volts
        if self.chain is not None:
            return self.chain.control(self, stamp, X)
        preview_stamp, positions, velocities, accelerations = self.latest_preview
        dt = (stamp - preview_stamp) * 1e-9
        self._control(stamp, X, shift_preview(positions, velocities, accelerations, dt),
                      velocities + dt * accelerations, accelerations, preview_stamp)

    # control ------------------------------------------------------------------------------------
    def _control(self, stamp: int, X: np.ndarray, positions: np.ndarray, velocities: np.ndarray,
                 accelerations: np.ndarray, preview_stamp: int) -> None:
        """One step on the odometry of `stamp` and the preview of `preview_stamp` (moved to `stamp`).

        `positions`, `velocities`, `accelerations` are the reference at `stamp` + j Ts, j = 0..N.
        """
        if not self.enabled:
            self._hold(stamp)
            return
        reason = self.blend.due(preview_stamp)
        first = self.previews.get(0) if self.plans is not None else None  # over a link tick 0 may be lost
        if reason == "start" and self.lockstep and (stamp == 0 or isinstance(first, tuple)):
            self.blend.reason = reason = None  # t = 0 of a lockstep run: robot and reference start together
            start = (positions if stamp == 0 else first[0])[0].tolist()
            (self.controller if self.plans is None else self.plans.controller).start_at(*start)
        try:
            if reason is not None:
                self._engage(stamp, X, positions[0], velocities[0], accelerations[0], reason)
                dt_s = None  # the controller starts over
            else:  # None: one period exactly, or the first tick
                dt_s = step_interval(stamp, self.last_odom_ns, self.period_ns)
            preview = positions[1:]
            offsets = self.blend.offsets(stamp)
            if offsets is not None:
                preview = preview + offsets
            if self.plans is not None:
                self._plan(stamp, X, preview, X[0::2] - positions[0], preview_stamp)
                return
            out = self.controller.step(X, preview, dt_s)
        except (ControllerInputError, BlendError) as exc:
            self._reject(stamp, "input", "controller", str(exc))
            return
        except Exception as exc:  # a bug must not leave the drives at the last voltages: zero, and start over
            error_throttled(self.get_logger(), f"control step failed: {exc!r}\n{traceback.format_exc()}", 1.0)
            self.blend.request("error")
            self._reject(stamp, "input", "internal_error", repr(exc))
            return
        self.last_odom_ns = stamp
        self.outputs.answer(stamp, list(self.controller.next_velocity() if self.outputs.cmd_vel else out.voltages))
        if self.outputs.path_wanted():
            self.outputs.publish_path(stamp, self.period_ns, self.controller.predicted_outputs())
        if not self.outputs.diagnosing():
            return
        error = X[0::2] - positions[0]
        flags = (out.saturated, out.infeasible)
        level = DiagnosticStatus.WARN if any(flags) else DiagnosticStatus.OK
        tracking = [f"{e:.9g}" for e in error.tolist()] + [
            f"{out.compute_time_s * 1e3:.4f}", str(flags[0]).lower(), str(flags[1]).lower(), str(preview_stamp),
            f"{self.control.period_s if dt_s is None else dt_s:.9g}"]
        self.outputs.diagnose(stamp, level, "tracking", tracking)

    def _hold(self, stamp: int) -> None:
        """Disabled: zero output for the odometry of `stamp` and the diagnostic ``disabled`` (through the chain, the
        zero twist noted in its controller's command model: the firmware gets it as any other command).
        """
        self.last_odom_ns = stamp
        if self.chain is not None:
            self.chain.note_zero(self.get_clock().now().nanoseconds)
        self.outputs.answer(stamp, [0.0, 0.0, 0.0])
        self.outputs.diagnose(stamp, DiagnosticStatus.OK, "disabled")

    def _plan(self, stamp: int, X: np.ndarray, preview: np.ndarray, error: np.ndarray, preview_stamp: int) -> None:
        """Plans: the plan of this odometry published, its first entry as the plain command (none for an
        odometry not newer than one taken: it came reordered or twice over the link).
        """
        begin = monotonic()
        plan = self.plans.plan(stamp, X, preview)
        if plan is None:
            self._drop(stamp, "odom", "old")
            return
        self.last_odom_ns = stamp
        self.outputs.answer(stamp, list(plan.entries[0]))
        if self.outputs.diagnosing():
            self.outputs.diagnose(stamp, DiagnosticStatus.OK, "tracking", [f"{e:.9g}" for e in error.tolist()] + [
                f"{(monotonic() - begin) * 1e3:.4f}", "false", "false", str(preview_stamp),
                f"{self.control.period_s:.9g}"])

    def _engage(self, stamp: int, X: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                acceleration: np.ndarray, reason: str) -> None:
        """Bumpless (re)start: reset the controller and blend the reference in from the measured state."""
        self.controller.reset()
        if self.plans is not None:
            self.plans.controller.reset()
        blend = self.blend.engage(stamp, X, position, velocity, acceleration, *self.blend_limits)
        if self.blend.blend is not None:
            limited = " (limit raised: the reference's own acceleration needs more)" if blend.limited else ""
            self.get_logger().info(
                f"bumpless restart ({reason}) at stamp {stamp} ns: offset {np.round(blend.dp, 6).tolist()}, "
                f"rate {np.round(blend.dv, 6).tolist()}, blended in over {blend.duration_s:.3f} s{limited}")

    def _event_values(self, stamp: int) -> list[str]:
        """The values of `_EVENT_KEYS` at `stamp` [ns] (every diagnostic carries them)."""
        return [self.watchdog_state, *self.counters.values(), f"{self.blend.remaining_s(stamp):.4f}",
                str(self.blend.engagements), *(self.plans.values() if self.plans is not None else ())]


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc controller_node``."""
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
