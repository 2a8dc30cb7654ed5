"""Plant simulator node: the Robotino (three DC drives + body, `RobotinoPlant`) on DDS.

Topics (relative names)
-----------------------
subscribes ``wheel_voltages``      std_msgs/Float64MultiArray, 3 values [V] (forward_command_controller convention),
           or ``cmd_vel``         geometry_msgs/Twist in base_link (``command_interface`` cmd_vel: held by the
                                  per-wheel PI speed loops of `wheel_speed_loop`, gains ``wheel_pi.*``)
publishes  ``odom``                nav_msgs/Odometry, frame ``odom`` -> child ``base_link`` (REP-105; both with
                                   ``frame_prefix``), true pose (``odometry_model`` encoders: dead-reckoned) plus
                                   the odometry noise, twist in ``base_link`` (true, or from encoder counts);
                                   covariances in `outputs`
           ``ground_truth/odom``   nav_msgs/Odometry, the noise-free state (for metrics)
           ``wheel_currents``      std_msgs/Float64MultiArray, 3 values [A], layout label ``wheel_current_a``: per
                                   drive the largest |armature current| over the control period that followed the
                                   previous measurement, signed like the current at its end (what
                                   `simulation.run_scenario` records); published after the next tick's odom and
                                   before its ground truth (and once more after the last period)
           ``applied_voltages``    cmd_vel only: the PI loops' mean voltages over those periods [V] (`outputs`)
           ``joint_states``        sensor_msgs/JointState of the wheels (`outputs`)
           ``/tf``                 tf2_msgs/TFMessage: odom -> base_link, the odometry's pose (``publish_tf``,
                                   `outputs`); frames ``<frame_prefix>odom``, ``<frame_prefix>base_link``
           ``/clock``              rosgraph_msgs/Clock (lockstep only)

The publishers use `publish_qos(lockstep)` (lockstep: keep-all, a slow recorder holds the loop back instead of
losing samples; realtime: keep-last, the loop never waits for an observer), the subscription `CONTROL_QOS`.

Commands: as an H-bridge, each voltage is clamped to +-``motor.supply_voltage_v`` (a throttled warning names
the commanded and applied voltages, a count). A refused command (not three finite values, malformed) means
zero volts from its arrival, in both modes (a throttled warning, a count).

Modes
-----
``realtime``: the plant runs on the steady clock, on a grid of 1 / ``physics_rate_hz``: each command and each
publish first integrates it up to the last grid point before now with the command held so far (zero volts once
that command is older than ``command_timeout_s``, as a real drive's watchdog does: `command_hold`, a throttled
warning, ``command_timeouts`` in the report), then applies the new command or sends the measurements. So there
is no physics timer (nothing wakes the process between events) and a command takes effect at most one grid
step late. A publish timer sends the measurements every control period, stamped with the node-clock time of
the grid point they belong to, once per grid point; after ``duration_s`` (if > 0) the node reports the loop's
timing as it saw it (`loop_timing.LoopTiming`) and exits.

``lockstep``: the plant owns time and repeats `simulation.run_scenario`'s tick: tick k is the state at t_k = k
Ts; it publishes the odometry (noise drawn from ``default_rng(seed)``, as the offline loop does), /clock and
the other measurements of tick k, waits for the command of tick k, integrates one control period with it, and
publishes tick k + 1 (if ``lockstep_max_realtime_factor`` > 0, not before its slot). Startup handshake: tick 0
goes out once the subscriptions of ``lockstep_wait_for`` are there and have settled (`lockstep_start`; what is
missing is logged). The current tick is published again (logged: which tick, since how long) when no command
arrives within ``lockstep_resend_s``, so no discovery race can deadlock the loop (the controller answers a
repeated tick only if its first answer could not be delivered, so no tick is answered twice). With
``duration_s`` > 0 the run has n = round(duration_s / Ts) ticks; when tick n - 1 is answered the node logs its
real-time factor and exits (status 0). The factor is that of the running loop: ticks 1 .. n - 1, from the
answer of tick 0 to the answer of the last tick; the wait for tick 0's answer (the end of discovery, which can
take a Fast DDS announcement period of 3 s) is logged apart. The report at the end of a run is one log line
and, if ``timing_report`` names a file, one JSON object there (`loop_timing` gives the keys and their
meaning), written once every reader has acknowledged the run's samples.
``chain.active`` enabled (realtime, cmd_vel): the plant behind the real robot's driver + firmware (`chain_driver`).
Networked (`plant_network`): ``link.up.*`` / ``link.down.*`` (`link_params`) put an emulated radio link between
the robot and everything off-board; ``plans`` takes plans instead of plain commands, reports ``command_applied``
(`plant_plans`). Parameters: the robot/control ones of config/*.yaml (``/**``) plus those in `PLANT_SPECS`.

Start: the node looks for another publisher of its ``odom`` topic on the ROS graph for ``odom_publisher_check_s``
from its creation, before it publishes anything (`odom_sources`); one found (a real driver's, another simulator's:
two sources of odometry are a fault), it exits with status 2 and an error naming the publisher's node.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from geometry_msgs.msg import Twist
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory

from robotino_geom_mpc.params.specs import ParamSpec
from robotino_geom_mpc.description.urdf import JOINT_NAMES, DescriptionError, check_frame_prefix
from robotino_geom_mpc.ros.cdr import CdrTemplate, MalformedMessage, cdr_reader
from robotino_geom_mpc.ros.messages import CURRENT_LABEL, VOLTAGE_LABEL, three_values_layout, three_values_template
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters, spec_defaults
from robotino_geom_mpc.ros.qos import CONTROL_QOS, publish_acknowledged, publish_qos
from robotino_geom_mpc.ros.spin import monotonic, run_node
from robotino_sim_node.chain_driver import CHAIN_NODE_DEFAULTS, CHAIN_NODE_SPECS, attach_chain
from robotino_geom_mpc.loop.link_queue import RobotLink
from robotino_geom_mpc.loop.command_hold import MAX_CHUNK, ZERO_VOLTS, CommandHold
from robotino_geom_mpc.model.encoders import ODOMETRY_DEFAULTS, ODOMETRY_SPECS, odometry_source, twist_covariance
from robotino_sim_node.link_params import LINK_DEFAULTS, LINK_SPECS, link_params, link_problem
from robotino_sim_node.lockstep_start import StartHandshake
from robotino_sim_node.odom_sources import ODOM_CHECK_DEFAULTS, ODOM_CHECK_SPECS, check_single_odom_source
from robotino_sim_node.loop_timing import LockstepPace, LoopTiming, clock_minus_steady_ns, realtime_report
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WHEEL_PI_DEFAULTS, WHEEL_PI_SPECS, WheelSpeedLoop
from robotino_sim_node.outputs import TF_DEFAULTS, TF_SPECS, AppliedVoltages, StateOutputs, odometry_template, \
    odometry_values
from robotino_sim_node.plant_lockstep import PlantLockstep
from robotino_sim_node.plant_network import PlantNetwork
from robotino_sim_node.plant_plans import PlantPlans
from robotino_sim_node.radio import Radio
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["PLANT_SPECS", "JOINT_NAMES", "PlantNode", "main"]

PLANT_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("mode", str, "realtime: wall timers; lockstep: advance one control period per command, publish /clock",
              choices=("realtime", "lockstep")),
    ParamSpec("duration_s", float, "Length of the run; 0 runs until stopped", "s", 0.0, 1e6, False),
    ParamSpec("physics_rate_hz", float, "Realtime: rate of the integration grid (commands apply on it)", "Hz", 1.0,
              1e5, False),
    ParamSpec("command_timeout_s", float, "Realtime: a command older than this means zero volts", "s", 0.0, 60.0, True),
    ParamSpec("lockstep_resend_s", float, "Lockstep: publish the current tick again after this long without a command",
              "s", 0.0, 60.0, True),
    ParamSpec("lockstep_max_realtime_factor", float, "Lockstep: at most this many simulated seconds per wall second "
              "(1: a deterministic run watched at real time); 0: as fast as the loop answers", "", 0.0, 1e6, False),
    ParamSpec("lockstep_settle_s", float, "Lockstep: send tick 0 this long after the start handshake is met, so "
              "that the other nodes' endpoints, shown by the graph, have matched each other too", "s", 0.0, 60.0, True),
    ParamSpec("odometry_noise.position_m", float, "Standard deviation of odometry x, y noise", "m", 0.0, 1.0, False),
    ParamSpec("odometry_noise.yaw_rad", float, "Standard deviation of the odometry yaw noise", "rad", 0.0, 1.0, False),
    ParamSpec("seed", int, "Seed of the odometry noise (and of the wheel slip)", "", 0, 2**31 - 1, False),
    ParamSpec("timing_report", str, "File the loop's timing figures go to as one JSON object at the end of a run "
              "(its folder must exist); empty: none"),
    ParamSpec("plans", bool, "Take the plans (wheel_voltage_plan / cmd_vel_plan) instead of the plain commands "
              "and report what was applied on command_applied"),
    ParamSpec("timing_window_s", float, "Realtime: report the figures per window this long too", "s", 0.0, 1e6, False),
) + ODOMETRY_SPECS + TF_SPECS + WHEEL_PI_SPECS + LINK_SPECS + CHAIN_NODE_SPECS + ODOM_CHECK_SPECS

_PLANT_DEFAULTS = {
    "mode": "realtime", "duration_s": 0.0, "physics_rate_hz": 1000.0, "command_timeout_s": 0.1, "seed": 0,
    "lockstep_resend_s": 0.5, "lockstep_max_realtime_factor": 0.0, "lockstep_settle_s": 1.0, "plans": False,
    "odometry_noise.position_m": 0.0, "odometry_noise.yaw_rad": 0.0, "timing_report": "", "timing_window_s": 0.0,
    **ODOMETRY_DEFAULTS, **TF_DEFAULTS, **WHEEL_PI_DEFAULTS, **LINK_DEFAULTS, **CHAIN_NODE_DEFAULTS,
    **ODOM_CHECK_DEFAULTS,
}

_read_command = cdr_reader(Float64MultiArray, "std_msgs/msg/Float64MultiArray")  # other layouts than the controller's
_MAX_BEHIND_S = 1.0  # realtime: a longer stall is skipped, not integrated


class PlantNode(PlantLockstep, PlantNetwork, Node):
    """The plant simulator node (see the module docstring for its interface)."""

    def __init__(self) -> None:
        super().__init__("robotino_plant")
        created = monotonic()  # the odometry sources' check counts its window from here (`odom_sources`)
        self.params = SpecParameters(
            self, _all_specs(), {**spec_defaults(), **_PLANT_DEFAULTS}, self._on_params,
            # the realtime grid (steps of 1 / physics_rate_hz), the odometry model
            fixed=("mode", "physics_rate_hz", "timing_report", "plans", *ODOMETRY_DEFAULTS, *TF_DEFAULTS,
                   *WHEEL_PI_DEFAULTS, *LINK_DEFAULTS, *CHAIN_NODE_DEFAULTS, *ODOM_CHECK_DEFAULTS), check=link_problem,
        )
        try:
            self.frame_prefix = check_frame_prefix(self.params["frame_prefix"])
        except DescriptionError as exc:
            raise NodeStartError(f"parameter 'frame_prefix': {exc}") from None
        report = self.params["timing_report"]
        if report and not Path(report).resolve().parent.is_dir():
            raise NodeStartError(f"parameter 'timing_report': folder of {report!r} does not exist")
        self.robot, self.control = self.params.robot_control()
        self.lockstep = self.params["mode"] == "lockstep"
        self.plant = self._new_plant(self.robot)
        self.odometry = self._new_odometry()
        self.period_ns = int(round(self.control.period_s * 1e9))
        self.rng = np.random.default_rng(self.params["seed"])  # the noise stream of `simulation.run_scenario`
        self.done, self.exit_status = Future(), 0

        qos = publish_qos(self.lockstep)
        self.odom_pub = self.create_publisher(Odometry, "odom", qos)
        self.truth_pub = self.create_publisher(Odometry, "ground_truth/odom", qos)
        self.current_pub = self.create_publisher(Float64MultiArray, "wheel_currents", qos)
        self.state_out = StateOutputs(self, qos, self.params["publish_tf"], self.frame_prefix)
        self.clock_pub = self.create_publisher(ClockMsg, "/clock", qos) if self.lockstep else None
        self.command_layout = three_values_layout(VOLTAGE_LABEL)
        p = self.params  # cmd_vel: a twist held by the wheel-speed PI loops instead of voltages
        self.speed_loop = WheelSpeedLoop(self.robot, p["wheel_pi.kp"], p["wheel_pi.ki"], p["wheel_pi.rate_hz"]) \
            if p["command_interface"] == "cmd_vel" else None
        self.applied = None if self.speed_loop is None else AppliedVoltages(self, qos)  # the PI loops' voltages
        self.plans = PlantPlans(self, p["command_interface"], self.control.period_s) if p["plans"] else None
        up, down = link_params(p.values, "up"), link_params(p.values, "down")
        self.networked = self.plans is not None or up.enabled or down.enabled  # else: as without a link
        self.radio = Radio(self, up, down, p["seed"]) if self.networked and not self.lockstep else None
        self.sim_link = RobotLink(up, down, p["seed"]) if self.networked and self.lockstep else None
        self.applied_pub = self.create_publisher(JointTrajectory, "command_applied", qos) if self.plans else None
        if self.plans is not None:
            self.command_sub = self.create_subscription(self.plans.msg_type, self.plans.topic, self._on_plan,
                                                        qos)  # lockstep: every answer of a tick is kept
        elif self.speed_loop is None:
            self.command_sub = self.create_subscription(Float64MultiArray, "wheel_voltages", self._on_command,
                                                        CONTROL_QOS, raw=True)
        else:
            self.command_sub = self.create_subscription(Twist, "cmd_vel", self._on_twist, CONTROL_QOS)
        self.handshake = StartHandshake(self, self.command_sub, {
            "odom": self.odom_pub, "ground_truth/odom": self.truth_pub, "wheel_currents": self.current_pub,
            "joint_states": self.state_out.joint_pub, "/tf": self.state_out.tf_pub, "/clock": self.clock_pub,
            "clock": self.clock_pub, "applied_voltages": self.applied and self.applied.pub,
            "command_applied": self.applied_pub})
        self.bundle: list | None = None  # networked: the messages of the tick being measured (one radio packet)
        if self.networked:
            self.state_out.send = self._send
            if self.applied is not None:
                self.applied.send = self._send

        self.peak_currents = np.zeros(3)
        self.measurement: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        self.have_period = False  # a period has been integrated since the first measurement
        self._build_messages()
        self.counts = {"clamped_commands": 0, "refused_commands": 0, "command_timeouts": 0}
        self.held: tuple[float, tuple[float, ...]] | None = None  # networked lockstep: (arrival, plain command)
        self.delivered: list[tuple[int, list]] = []  # networked lockstep: this tick's bundles (stamp, messages)
        self.expected = self.answers = 0  # networked lockstep: answers due this tick, received
        self.tick = 0
        duration = self.params["duration_s"]
        self.last_tick = max(1, int(round(duration / self.control.period_s))) - 1 if duration > 0 else None
        self.busy_s = 0.0  # in the callbacks (lockstep: ticks 1 ..)
        # nothing published and no callback run yet; the publishers match their readers meanwhile
        check_single_odom_source(self, self.odom_pub, created, self.params["odom_publisher_check_s"])
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if self.lockstep:
            self.pace = LockstepPace(self.params["lockstep_max_realtime_factor"], self.control.period_s)
            self.pace_timer = self.create_timer(1.0, self._paced_tick, clock=steady, autostart=False)  # per held tick
            self.started = False
            self.wait_s = 0.0  # waiting for commands (ticks 1 ..)
            self.published_at = self.tick_sent_at = monotonic()  # the last (re)send; the tick's first send
            self.resent = 0
            self.start_timer = self.create_timer(0.01, self._try_start, clock=steady)
            self.resend_timer = self.create_timer(self.params["lockstep_resend_s"] / 2, self._resend, clock=steady)
        else:
            self.started_at = monotonic()
            self.clock_offset_s = clock_minus_steady_ns(self) * 1e-9  # robot - steady
            self.hold = CommandHold(self.started_at, 1.0 / self.params["physics_rate_hz"])  # a refused one: 0 V
            self.ticks, self.published_grid_s = 0, -math.inf  # published; the last one's grid point [s, steady]
            self.timing = LoopTiming(window_s=self.params["timing_window_s"])
            self.publish_timer = self.create_timer(self.control.period_s, self._publish_realtime, clock=steady)
        self.chain = attach_chain(self)  # chain.active: the driver + firmware chain takes commands and odometry
        self.get_logger().info(f"plant simulator ready ({self.params['mode']}, Ts = {self.control.period_s:g} s)")

    # parameters ---------------------------------------------------------------------------------
    def _on_params(self, changed: dict) -> None:
        robot, self.control = self.params.robot_control()
        if robot != self.robot:
            self.robot = robot
            self.plant = self._new_plant(robot, self.plant.state)
            self.odometry = self._new_odometry(self.odometry)
        self._build_messages()
        if self.lockstep:
            self.pace = LockstepPace(self.params["lockstep_max_realtime_factor"], self.control.period_s)
        if "seed" in changed:
            self.rng = np.random.default_rng(self.params["seed"])

    def _new_plant(self, robot, state=None) -> RobotinoPlant:
        """A plant at `state`; in realtime with the matrices of every step size `_advance` uses computed now."""
        plant = RobotinoPlant(robot, state0=state)
        if not self.lockstep:
            for k in range(1, MAX_CHUNK + 1):  # an uncached step size costs milliseconds of expm
                plant.step(ZERO_VOLTS, k / self.params["physics_rate_hz"])
            plant.reset(state)
        return plant

    def _new_odometry(self, previous=None):
        """What the odometry reads (`encoders.odometry_source`); encoders continue from `previous`'s pose."""
        p = self.params
        return odometry_source(self.plant, p["odometry_model"], p["encoder.counts_per_rev"],
                               p["encoder.wheel_slip_std"], p["seed"], getattr(previous, "pose", None))

    # lockstep (the run's start, resends, pace, report: `plant_lockstep`) ----------------------------
    def _time_ns(self) -> int:
        return self.tick * self.period_ns

    def _publish_tick(self, fresh: bool) -> None:
        """Odometry first (the controller's critical path), then /clock, the currents and the rest."""
        if self.sim_link is not None:
            if fresh:
                self._network_run()
            else:
                self._network_tick(fresh=False)
            return
        self._publish_measurements(divmod(self._time_ns(), 1_000_000_000), fresh, clock=True)
        self.published_at = monotonic()
        if fresh:
            self.tick_sent_at = self.published_at

    def _drive(self, command: np.ndarray, dt: float) -> np.ndarray:
        """Integrate `dt` under the command (voltages held, or a twist through the wheel-speed loops): peak |i|."""
        if self.speed_loop is None:
            self.plant.step(command, dt)
            return self.plant.peak_abs_currents
        return self.applied.drive(self.speed_loop, self.plant, command, dt)

    def _on_twist(self, msg: Twist) -> None:
        values = (msg.linear.x, msg.linear.y, msg.angular.z)
        valid = math.isfinite(sum(values))
        if not valid:
            self.counts["refused_commands"] += 1
            warn_throttled(self.get_logger(), f"refused cmd_vel {values}: zero twist from now", 1.0)
            values = (0.0, 0.0, 0.0)
        self._apply(values, valid)

    def _on_command(self, data: bytes) -> None:
        values = self.command_layout.read(data)  # the controller's layout, read in place; else decoded
        if values is None:
            try:
                values = tuple(_read_command(data).data)
            except MalformedMessage:
                values = ()
        valid = len(values) == 3 and math.isfinite(sum(values))
        if not valid:
            self.counts["refused_commands"] += 1
            warn_throttled(self.get_logger(), f"refused wheel_voltages with {len(values)} values (need 3 finite "
                           f"values): zero volts from now ({self.counts['refused_commands']} refused so far)", 1.0)
            values = (0.0, 0.0, 0.0)
        elif max(values) > self.robot.supply_voltage_v or min(values) < -self.robot.supply_voltage_v:
            values = self._clamp(values)
        self._apply(values, valid)

    def _apply(self, values: tuple[float, ...], valid: bool) -> None:
        """A command (voltages or twist): held from the next grid point (realtime), or the tick's period."""
        if self.sim_link is not None:
            self._answer(values)
            return
        if self.radio is not None:  # it arrives when the link delivers it
            self.radio.send("down", lambda: self._hold_command(values, valid))
            return
        if not self.lockstep:
            self._hold_command(values, valid)
            return
        if not self.started or self.done.done():
            return
        begin = monotonic()
        if self._lockstep_period(values):
            self._publish_tick(fresh=True)
        self.busy_s += monotonic() - begin

    def _hold_command(self, values: tuple[float, ...], valid: bool) -> None:
        """Realtime: the command held from the next grid point."""
        begin = monotonic()
        if valid:
            self.timing.command(begin)
        self._advance(begin, ceil=True)  # the old command up to now; the new one from the next grid point
        self.hold.hold(values, begin)
        self.busy_s += monotonic() - begin

    def _clamp(self, values: tuple[float, ...]) -> tuple[float, ...]:
        """`values` clamped to the supply, as an H-bridge applies them; a throttled warning and a count."""
        supply = self.robot.supply_voltage_v
        applied = tuple(min(max(v, -supply), supply) for v in values)
        self.counts["clamped_commands"] += 1
        warn_throttled(self.get_logger(), f"wheel_voltages {', '.join(f'{v:g}' for v in values)} V beyond the supply "
                       f"+-{supply:g} V: applied {', '.join(f'{v:g}' for v in applied)} V "
                       f"({self.counts['clamped_commands']} commands clamped so far)", 1.0)
        return applied

    # realtime -----------------------------------------------------------------------------------
    def _advance(self, now: float, ceil: bool = False) -> float:
        """Integrate up to the grid point before (`ceil`: after) steady time `now`; returns the plant's time."""
        hold = self.hold
        position = (now - self.started_at) / hold.dt
        target = math.ceil(position) if ceil else math.floor(position)
        if target - hold.grid > _MAX_BEHIND_S / hold.dt:  # the process stalled: skip rather than catch up
            warn_throttled(self.get_logger(), f"plant {(target - hold.grid) * hold.dt:.2f} s behind: skipping ahead")
            hold.grid = target
        if self.plans is not None:
            self._advance_plans(target)
            return self.started_at + hold.grid * hold.dt
        timeout = self.params["command_timeout_s"]
        if hold.advance(target, timeout, self._drive_for_peak):
            self.counts["command_timeouts"] += 1
            warn_throttled(self.get_logger(), f"no command for {timeout:g} s: zero volts (drive watchdog; "
                                   f"{self.counts['command_timeouts']} so far)", 1.0)
        return self.started_at + hold.grid * hold.dt

    def _drive_for_peak(self, voltages: np.ndarray, dt: float) -> None:
        self.peak_currents = np.maximum(self.peak_currents, self._drive(voltages, dt))

    def _publish_realtime(self) -> None:
        now = monotonic()
        if self.last_tick is not None and now - self.started_at >= self.params["duration_s"]:
            self.get_logger().info(f"realtime run over: {self.timing.summary()}; {self.counts['clamped_commands']} "
                                   f"commands clamped, {self.counts['refused_commands']} refused, "
                                   f"{self.counts['command_timeouts']} timed out")
            simulated = self.hold.grid * self.hold.dt
            self._write_report(realtime_report(self.timing, self.ticks, simulated, now - self.started_at,
                                               self.busy_s, **self.counts))
            self.done.set_result(True)
            return
        if (grid_time := self._advance(now)) <= self.published_grid_s:  # a late timer firing again: no new state
            return
        self.published_grid_s = grid_time
        self.timing.published(monotonic())
        if self.radio is not None:  # the robot clock of the grid point; the tick's packet leaves over the link
            stamp_ns = int(round((self.clock_offset_s + grid_time) * 1e9))
            bundle = self._measure_bundle(divmod(stamp_ns, 1_000_000_000))
            self.radio.send("up", lambda: self._publish_bundle(bundle), stamp_ns * 1e-9)
        else:
            stamp_ns = clock_minus_steady_ns(self) + round(grid_time * 1e9)  # the node clock at the grid time
            self._publish_measurements(divmod(stamp_ns, 1_000_000_000), fresh=True)
        self.have_period = True
        self.ticks += 1
        self.busy_s += monotonic() - now

    # measurements -------------------------------------------------------------------------------
    def _build_messages(self) -> None:
        """Serialized templates (frames, names, covariances set once) patched each tick (`CdrTemplate`)."""
        p = self.params
        twist = None if p["odometry_model"] == "ideal" else twist_covariance(
            self.robot, p["encoder.counts_per_rev"], p["encoder.wheel_slip_std"], self.control.period_s)
        self.odom_cdr = odometry_template(p["odometry_noise.position_m"], p["odometry_noise.yaw_rad"],
                                          self.frame_prefix, twist)
        self.truth_cdr = odometry_template(0.0, 0.0, self.frame_prefix)
        self.current_cdr = three_values_template(CURRENT_LABEL)
        self.clock_cdr = CdrTemplate(ClockMsg(), ("clock.sec", "clock.nanosec"))
        self.effort_per_a = self.robot.gear_ratio * self.robot.torque_constant_n_m_per_a

    def _publish_currents(self) -> None:
        """Signed peak current of each drive over the period just integrated (as `simulation` records it)."""
        if self.applied is not None:  # cmd_vel: the PI loops' mean voltages over that period, just before
            self.applied.publish()
        if self.current_pub.get_subscription_count():
            self._send(self.current_pub, self.current_cdr.pack(*np.copysign(self.peak_currents,
                                                                            self.plant.currents).tolist()))
        self.peak_currents = np.zeros(3)

    def _publish_measurements(self, stamp: tuple[int, int], fresh: bool, clock: bool = False) -> None:
        """Odom (noisy), /clock, currents, ground truth, joints at `stamp` (sec, nanosec); a resent tick (not
        `fresh`): odom and /clock only (they drive the loop; tf2 refuses a repeated stamp on /tf). The others are
        built only while a subscription is matched; the currents of the period just integrated follow this
        tick's odometry, before its ground truth.
        """
        if fresh or self.measurement is None:
            noise = (self.params["odometry_noise.position_m"], self.params["odometry_noise.yaw_rad"])
            self.measurement = self.odometry.odometry_floats(self.rng, noise)
        self._send(self.odom_pub, self.odom_cdr.pack(*stamp, *odometry_values(*self.measurement)))
        if clock:
            publish_acknowledged(self, self.clock_pub, self.clock_cdr.pack(*stamp))
        if not fresh:
            return
        if self.have_period:
            self._publish_currents()
        if self.truth_pub.get_subscription_count():
            self._send(self.truth_pub, self.truth_cdr.pack(*stamp, *odometry_values(*self.plant.odometry_floats())))
        plant = self.plant
        self.state_out.publish(stamp, self.measurement[0], plant.wheel_angles.tolist(), plant.wheel_speeds.tolist(),
                               (self.effort_per_a * plant.currents).tolist())


def _all_specs() -> tuple[ParamSpec, ...]:
    from robotino_geom_mpc.params.specs import ALL_SPECS
    return ALL_SPECS + PLANT_SPECS


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc plant_node``."""
    return run_node(PlantNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
