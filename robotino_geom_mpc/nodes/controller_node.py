"""Controller node: one `MotionController.step` (three MPCs, eq. 56 -> T(theta), eqs. 33-37 -> inverse drive) a tick.

Topics (relative names)
-----------------------
subscribes ``odom``               nav_msgs/Odometry (pose in ``odom``, twist in ``base_link``)
           ``reference_preview``  trajectory_msgs/MultiDOFJointTrajectory (N + 1 points or more, see trajectory_node)
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
                                  ``dropped_old``, ``blend_remaining_s``, ``blend_engagements``,
                                  ``clock_ns`` (the node clock at the input), ``preview_clock_ns`` (the
                                  node clock when it took the newest preview; empty before any). Built
                                  and sent only while a subscription is matched.
           ``predicted_path``     nav_msgs/Path in ``<frame_prefix>odom``: the MPCs' y(k+1) .. y(k+N) (eq. 50
                                  under the optimal increments of eq. 56), pose j stamped t_k + j Ts; computed
                                  and sent only while a subscription is matched (``publish_predicted_path``
                                  false: no publisher).
services   ``~/enable``           std_srvs/SetBool. Disabled: zero output every tick (diagnostic message
                                  ``disabled``; realtime: on every odometry, with or without a reference; with
                                  plans also a plan of zeros, which replaces the plans the robot holds), the
                                  controller holds its state; enabled again: bumpless restart. ``start_enabled``
                                  false starts the node disabled (the first enable is its bumpless start).
publishes  ``controller_enabled`` std_msgs/Bool, `LATCHED_QOS` (reliable, transient local, depth 1): the enabled
                                  state, at start and on every change (a trajectory node with
                                  ``start_on_enable`` starts its reference when it turns true).

The node is an adapter: each callback decodes its message (in place by a `ros.cdr.CdrLayout`, any other layout
by `ros.cdr.cdr_reader`), hands it with the time (`loop.events.Now`: the node clock and the watchdog's clock) to
its `loop.controller_loop.ControllerLoop`, which decides everything below, and `controller_outputs.ControllerOutputs`
publishes what the loop answers. The watchdog's timer, ``~/enable``, a parameter set and the stop do the same.

Each odometry message is one control tick: the node computes on its arrival. The preview used is the one
whose stamp equals the odometry stamp in ``lockstep`` (the odometry waits for it if it comes first), the
freshest in ``realtime``, moved in time to the odometry's stamp with its velocities and accelerations
(`reference.trajectories.preview_at`; a preview longer than N + 1 points, from a trajectory node
with ``preview_every`` > 1, gives its rows of the periods elapsed first). The step gets ``dt_s`` = the
interval between the stamps of this odometry and of the last one used (None when it is exactly one period,
and after a (re)start).

Time: the stamps of the inputs; in realtime the node clock (``use_sim_time`` honoured) is read once per
input to check its stamp. The watchdog counts the node clock under ``use_sim_time`` (read at start),
steady time otherwise. Frames: a preview not in ``<frame_prefix>odom`` is refused (reason ``frame``).

Bad input, stale data and the stop: `controller_inputs` (zero volts and a diagnostic naming the reason).
Plans (``plans``, an off-board controller over a network): delay-compensated plans
(`control.delay_compensation.DelayCompensatingController`) on ``wheel_voltage_plan`` / ``cmd_vel_plan``
(`ros.plans`), the plain command carrying the plan's first entry (``publish_plain_command`` false: none, where a
robot-side command buffer drives the driver's ``cmd_vel``); a plan of zeros that replaces the plans the robot holds
on every disabled tick, and with the zero of the watchdog, a refusal or the stop once until it plans again (after
a first plan); the robot's ``command_applied``
(trajectory_msgs/JointTrajectory) read and handed to the loop in the order it came (in lockstep held while an
odometry waits for its preview); a report that cannot be read or lies more than 2 s from the newest odometry is
refused (``refused_reports``); the link in the diagnostics (`loop.controller_loop.LINK_KEYS`: round trip mean,
jitter and the lead's quantile [s], the lead [periods], plans sent / received / lost, odometries received /
missing / stale, ``exhausted_periods``, ``refused_reports``, ``reports_received``). In lockstep the odometries of a
tick are answered in arrival order, each with the preview of its stamp; the answers (commands, with plans the
plans) go out once their publisher has matched ``lockstep_command_readers`` readers (the plant's and a
recorder's: `controller_outputs`), held until then; an answer is never sent twice.
Chain (``chain.active`` enabled: realtime, cmd_vel): the chain controller (`control.chain_controller`, built from
``chain.*``: the preset, or `identify`'s file) steps on each odometry instead of the MPC, with the newest preview
and the node clock at the step; two odometries of one driver pass share a stamp and both are used, an old stamp
too (a dispatch time); every zero twist the node sends is noted in its command model; disabled, each odometry is
answered with a zero twist, noted as well, and enabled again it goes on from its model (no blend: the one-move
plan's braking limit keeps within the firmware's ramps). Its status per tick (message ``chain``) names
``preview_stamp_ns``. Every status (every mode) carries the node clock at its input, ``clock_ns``, and when it
took the newest preview, ``preview_clock_ns``: a recording replays exactly, also of a node that fell behind.

One reference source: the loop pairs with the first publisher of ``reference_preview`` (told apart by
`ros.source_gate.SourceGate`) and refuses the previews of any other while the paired one's are fresh
(``reference_timeout_s``): counted (``refused_second_source`` in the diagnostics), a throttled warning naming the
other publishers from the ROS graph; the paired trajectory goes on unaffected (no blending back and forth).

Bumpless (re)start (`control.blend.BlendEngagement`): at the first tick (except tick t = 0 of a lockstep
run, where robot and reference start together as in `simulate`), after stale data or ``~/enable`` turned
on again, at a preview whose reference jumped (more than ``reference_jump_m`` / ``reference_jump_rad``
from the previous preview moved to its stamp, e.g. a restarted trajectory node) and after a parameter
change, the controller is reset (u(k-1) = 0, pose filter restarted) and a C^3 offset o(t) is added to the
preview, taking the reference from the measured pose and velocity to itself within the shortest time
whose offset acceleration stays within ``blend_acceleration_mps2`` / ``blend_acceleration_radps2``.

Parameters: the robot/control parameters of config/*.yaml (``/**`` section) plus
`controller_inputs.CONTROLLER_SPECS` and ``chain.*``. A set is refused with the reason when the values cannot run
(`controller_inputs.closed_loop_problem`: a timeout under two periods, an unstable nominal closed loop, a model
the controller cannot be built on; also at start: exit status 2) and for ``mode``, ``frame_prefix``,
``command_interface``, ``control.period_s`` and ``control.horizon`` (the last two must agree with the trajectory
node: restart instead); any other accepted change of a robot/control parameter rebuilds the controller with a
bumpless restart.
"""

from __future__ import annotations

import time
from typing import Any

from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.timer import Timer
from std_srvs.srv import SetBool
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

from robotino_geom_mpc.description.urdf import DescriptionError, check_frame_prefix
from robotino_geom_mpc.loop.controller_loop import ControllerLoop, LoopConfigError, LoopSettings
from robotino_geom_mpc.loop.events import AppliedReport, Now, Odometry as OdometryIn, Preview, Undecodable
from robotino_geom_mpc.model.driver_chain import (CHAIN_NODE_DEFAULTS, CHAIN_NODE_SPECS, ChainError, ChainParams,
                                                  chain_params)
from robotino_geom_mpc.nodes.controller_inputs import CONTROLLER_DEFAULTS, CONTROLLER_SPECS, FIXED_WHILE_RUNNING, \
    closed_loop_problem
from robotino_geom_mpc.nodes.controller_outputs import ControllerOutputs
from robotino_geom_mpc.params.specs import ALL_SPECS, CHAIN_ACTIVE_SPEC, CHAIN_SPECS
from robotino_geom_mpc.ros.cdr import MalformedMessage, cdr_reader
from robotino_geom_mpc.ros.decode import InputRejected, odometry_values, preview_point_values, time_ns
from robotino_geom_mpc.ros.messages import ODOM_FRAME, PreviewLayouts, odometry_layout
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters, spec_defaults
from robotino_geom_mpc.ros.plans import PlanMessageError, report_of_message
from robotino_geom_mpc.ros.qos import CONTROL_QOS, LATEST_QOS, LOCKSTEP_PUBLISH_QOS, publish_qos
from robotino_geom_mpc.ros.source_gate import SourceGate, WithInfo
from robotino_geom_mpc.ros.spin import run_node

__all__ = ["CONTROLLER_SPECS", "ControllerNode", "main"]

# the general decoders (field names are all `odometry_values` and `preview_point_values` use, so either one fits)
_read_odom = cdr_reader(Odometry, "nav_msgs/msg/Odometry")
_read_preview = cdr_reader(MultiDOFJointTrajectory, "trajectory_msgs/msg/MultiDOFJointTrajectory")

_ROBOT_CONTROL = frozenset(s.name for s in ALL_SPECS)
_SETTINGS = ("odom_timeout_s", "reference_timeout_s", "future_tolerance_s", "quaternion_norm_tolerance",
             "tilt_tolerance_rad", "reference_jump_m", "reference_jump_rad", "blend_acceleration_mps2",
             "blend_acceleration_radps2")


class ControllerNode(Node):
    """The controller node (see the module docstring for its interface)."""

    def __init__(self, **node_options: Any) -> None:
        """`node_options`: rclpy's `Node` options (a fleet's robot: its ``namespace`` and parameter overrides)."""
        super().__init__("robotino_controller", **node_options)
        defaults = {**spec_defaults(), **CONTROLLER_DEFAULTS, **CHAIN_NODE_DEFAULTS}
        self.params = SpecParameters(self, ALL_SPECS + CONTROLLER_SPECS + CHAIN_NODE_SPECS, defaults, self._on_params,
                                     fixed=(*FIXED_WHILE_RUNNING, *CHAIN_NODE_DEFAULTS), check=closed_loop_problem)
        robot, control = self.params.robot_control()
        lockstep = self.params["mode"] == "lockstep"
        interface = self.params["command_interface"]
        try:
            prefix = check_frame_prefix(self.params["frame_prefix"])
        except DescriptionError as exc:
            raise NodeStartError(f"parameter 'frame_prefix': {exc}") from None
        # the watchdog's clock, read at start: the node clock under use_sim_time (a slow simulation is slow, not
        # stale), else steady time
        self.sim_time = bool(self.get_parameter("use_sim_time").value)
        self.outputs = ControllerOutputs(self, lockstep, prefix, interface,
                                         control.plan_length if self.params["plans"] else None,
                                         self.params["publish_predicted_path"], self.params["lockstep_command_readers"],
                                         self.params["publish_plain_command"])
        try:
            self.loop = ControllerLoop(robot, control, self._now(), self._settings(), lockstep=lockstep,
                                       interface=interface, plans=self.params["plans"], chain=self._chain(),
                                       enabled=self.params["start_enabled"], odom_frame=prefix + ODOM_FRAME,
                                       listeners=self.outputs)
        except LoopConfigError as exc:
            raise NodeStartError(str(exc)) from None
        self.enable_srv = self.create_service(SetBool, "~/enable", self._on_enable)
        self.outputs.send_enabled(self.loop.enabled)
        self.odom_layout = odometry_layout(prefix)  # other frames are read by the general decoder
        self.preview_layouts = PreviewLayouts(control.period_s, self.loop.preview_points, prefix)  # longer: learnt
        # lockstep plans: the previews of the ticks before an odometry's late delivery are all kept
        qos = LOCKSTEP_PUBLISH_QOS if self.params["plans"] and lockstep else CONTROL_QOS
        # realtime: the newest odometry only; the chain's controller reads every sample of the driver's bursts
        newest = not lockstep and self.loop.chain is None
        self.odom_sub = self.create_subscription(Odometry, "odom", self._on_odom, LATEST_QOS if newest else qos,
                                                 raw=True)
        self.preview_gate = SourceGate(self, "reference_preview")
        self.preview_sub = self.create_subscription(MultiDOFJointTrajectory, "reference_preview",
                                                    WithInfo(self._on_preview), qos, raw=True)
        if self.params["plans"]:  # every report (keep-all in lockstep)
            self.report_sub = self.create_subscription(JointTrajectory, "command_applied", self._on_report,
                                                       publish_qos(lockstep))
        self.watchdog = self._start_watchdog()
        disabled = "" if self.loop.enabled else \
            f"; disabled (zero output) until {self.resolve_service_name(self.enable_srv.srv_name)} true"
        self.get_logger().info(f"controller ready ({self.params['mode']}, mode {control.mode}, "
                               f"N = {control.horizon}, Ts = {control.period_s:g} s){disabled}")

    # time and parameters ------------------------------------------------------------------------
    def _now(self) -> Now:
        """The node clock and the watchdog's clock (the node clock under use_sim_time, else steady time)."""
        clock = self.get_clock().now().nanoseconds
        return Now(clock, clock if self.sim_time else time.monotonic_ns())

    def _settings(self) -> LoopSettings:
        return LoopSettings.of({name: self.params[name] for name in _SETTINGS})

    def _chain(self) -> ChainParams | None:
        """The chain's parameters when ``chain.active`` is enabled (the chain controller), else None."""
        if self.params[CHAIN_ACTIVE_SPEC.name] != "enabled":
            return None
        try:
            return chain_params({spec.name: self.params[spec.name] for spec in CHAIN_SPECS},
                                where="the controller's parameters")
        except ChainError as exc:
            raise NodeStartError(str(exc)) from None

    def _start_watchdog(self) -> Timer:
        """The watchdog's timer, at half the shorter timeout, on the watchdog's clock."""
        clock = self.get_clock() if self.sim_time else Clock(clock_type=ClockType.STEADY_TIME)
        return self.create_timer(self.loop.settings.watchdog_period_s, self._on_watchdog, clock=clock)

    def _on_params(self, changed: dict) -> None:
        rebuild = bool(_ROBOT_CONTROL & changed.keys())
        robot, control = self.params.robot_control() if rebuild else (self.loop.robot, self.loop.control)
        self.outputs.send(self.loop.on_parameters(robot, control, self._settings(), rebuild, self._now()))
        if {"odom_timeout_s", "reference_timeout_s"} & changed.keys():
            self.destroy_timer(self.watchdog)
            self.watchdog = self._start_watchdog()
        if rebuild:
            self.get_logger().info(f"parameters {sorted(changed)} changed: controller rebuilt, bumpless restart")

    def on_stop(self) -> None:
        """Realtime: leave the drives at zero volts (a base at zero twist) as the node stops (`ros.spin.run_node`).

        Lockstep does not: the plant holds the time and pairs every command with its tick.
        """
        self.outputs.send(self.loop.on_stop(self._now()))

    # inputs -------------------------------------------------------------------------------------
    def _on_enable(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """~/enable: false holds (zero output every tick, the controller untouched); true re-engages bumplessly."""
        self.outputs.send(self.loop.on_enable(request.data, self._now()))
        response.success, response.message = True, "enabled" if self.loop.enabled else "disabled"
        return response

    def _on_watchdog(self) -> None:
        self.outputs.send(self.loop.on_watchdog(self._now()))

    def _on_odom(self, data: bytes) -> None:
        now = self._now()
        try:
            values = self.odom_layout.read(data)
            if values is None:
                values = odometry_values(_read_odom(data))
            odom = OdometryIn(time_ns(values[0], values[1]), tuple(values[2:]))
        except (MalformedMessage, InputRejected) as exc:
            bad = Undecodable("odom", None, getattr(exc, "reason", "malformed"), str(exc))
            self.outputs.send(self.loop.on_undecodable(bad, now))
            return
        self.outputs.send(self.loop.on_odometry(odom, now))

    def _on_preview(self, data: bytes, info: dict[str, Any]) -> None:
        now = self._now()
        stamp = None
        source = self.preview_gate.source(info)
        try:
            values = self.preview_layouts.read(data)
            if values is None:
                msg = _read_preview(data)
                stamp = time_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)  # a malformed one: refused for its tick
                preview = Preview(stamp, msg.header.frame_id, preview_point_values(msg, None), source)
                self.preview_layouts.learn(data, len(msg.points))
            else:
                preview = Preview(time_ns(values[0], values[1]), self.loop.odom_frame, tuple(values[2:]), source)
        except (MalformedMessage, InputRejected) as exc:
            bad = Undecodable("reference_preview", stamp, getattr(exc, "reason", "malformed"), str(exc))
            self.outputs.send(self.loop.on_undecodable(bad, now))
            return
        self.outputs.send(self.loop.on_preview(preview, now))
        sources = self.loop.sources
        if sources.holder == source:
            self.preview_gate.note(sources)
        else:
            self.preview_gate.refused(sources, source)

    def _on_report(self, msg: JointTrajectory) -> None:
        now = self._now()
        report: AppliedReport | Undecodable
        try:
            report = report_of_message(msg)
        except PlanMessageError as exc:
            report = Undecodable("command_applied", None, exc.reason, str(exc))
        self.outputs.send(self.loop.on_report(report, now))


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc controller_node``."""
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
