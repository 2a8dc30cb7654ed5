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
that command is older than ``command_timeout_s``, as a real drive's watchdog does: `loop.command_hold`, a
throttled warning, ``command_timeouts`` in the report), then applies the new command or sends the measurements. So there
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
arrives within ``lockstep_resend_s``, so no discovery race can deadlock the loop (the controller never sends an
answer twice: it holds its answers until the writer of their topic, the command's or with plans the plan's, has
matched its ``lockstep_command_readers``, and a repeated tick only releases answers still held). With
``duration_s`` > 0 the run has n = round(duration_s / Ts) ticks; when tick n - 1 is answered the node logs its
real-time factor and exits (status 0). The factor is that of the running loop: ticks 1 .. n - 1, from the
answer of tick 0 to the answer of the last tick; the wait for tick 0's answer (the end of discovery, which can
take a Fast DDS announcement period of 3 s) is logged apart. The report at the end of a run is one log line
and, if ``timing_report`` names a file, one JSON object there (`loop_timing` gives the keys and their
meaning), written once every reader has acknowledged the run's samples.
``chain.active`` enabled (realtime, cmd_vel): the plant behind the real robot's driver + firmware (`chain_driver`).
Networked: ``link.up.*`` / ``link.down.*`` (`link_params`) put an emulated radio link between the robot and
everything off-board (lockstep: `plant_lockstep`, realtime: `plant_realtime`, `radio`); ``plans`` takes plans
instead of plain commands, reports ``command_applied`` (`plant_plans`). Parameters: the robot/control ones of
config/*.yaml (``/**``) plus those in `PLANT_SPECS`.

Structure: the node is wiring. The robot (plant, odometry, drive, commands checked, measurements) is a
`loop.robot_loop.RobotLoop`; how time advances is chosen once, at the start: `plant_lockstep.LockstepRun` over
`LockstepTicks` (with `loop.command_link.CommandLink` over a link), `plant_realtime.RealtimeRun` over
`RealtimeGrid`, or `chain_driver.ChainRun` over `loop.chain_robot.ChainRobot`. The subscriptions decode and hand
each command to the run; `outputs.PlantOutputs` turns the measurements into messages.

One controller at a time: the plant pairs with the first source of commands (``wheel_voltages``, ``cmd_vel`` or
the plans) after its start or a ``~/release`` (std_srvs/Trigger) and refuses every other one while the paired
controller has sent within ``pairing.lease_s`` (`loop.robot_loop.RobotLoop.admit`): the refused command is not
applied (the paired controller's command stays), it is counted (``refused_second_source``, also in the timing
report) and a throttled warning names the topic's other publishers from the ROS graph (`ros.source_gate`). Its
``diagnostics`` (diagnostic_msgs/DiagnosticArray, status ``robotino_geom_mpc: plant``: the paired publisher, the
refusals, the last second source named, the command counts) go out once a second while commands are refused, and
once when a controller has taken the robot after a release; a plant driven by one controller publishes none.

Start: the node looks for another publisher of its ``odom`` topic on the ROS graph for ``odom_publisher_check_s``
from its creation, before it publishes anything (`odom_sources`); one found (a real driver's, another simulator's:
two sources of odometry are a fault), it exits with status 2 and an error naming the publisher's node. In
lockstep the start handshake is polled during that window, so its ``lockstep_settle_s`` runs alongside it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Twist
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from robotino_geom_mpc.description.urdf import JOINT_NAMES, DescriptionError, check_frame_prefix
from robotino_geom_mpc.loop.command_hold import warm_up
from robotino_geom_mpc.loop.command_link import CommandLink
from robotino_geom_mpc.loop.plan_follower import PlanFollower
from robotino_geom_mpc.loop.robot_loop import LockstepTicks, OdometrySource, PoseNoise, RealtimeGrid, RobotLoop, \
    TwistDrive, VoltageDrive
from robotino_geom_mpc.model.encoders import ODOMETRY_DEFAULTS, ODOMETRY_SPECS, odometry_source
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WHEEL_PI_DEFAULTS, WHEEL_PI_SPECS, WheelSpeedLoop
from robotino_geom_mpc.params.specs import ParamSpec, RobotinoParams
from robotino_geom_mpc.ros.cdr import MalformedMessage, cdr_reader
from robotino_geom_mpc.ros.messages import VOLTAGE_LABEL, three_values_layout
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters, spec_defaults
from robotino_geom_mpc.ros.qos import CONTROL_QOS, PUBLISH_QOS, publish_qos
from robotino_geom_mpc.ros.source_gate import PAIRING_DEFAULTS, PAIRING_SPECS, SourceGate, WithInfo
from robotino_geom_mpc.ros.spin import monotonic, run_node
from robotino_sim_node.chain_driver import CHAIN_NODE_DEFAULTS, CHAIN_NODE_SPECS, ChainRun, chain_of
from robotino_sim_node.link_params import LINK_DEFAULTS, LINK_SPECS, link_params, link_problem
from robotino_sim_node.lockstep_start import StartHandshake
from robotino_sim_node.loop_timing import clock_minus_steady_ns
from robotino_sim_node.odom_sources import ODOM_CHECK_DEFAULTS, ODOM_CHECK_SPECS, check_single_odom_source
from robotino_sim_node.outputs import TF_DEFAULTS, TF_SPECS, PlantOutputs
from robotino_sim_node.plant_lockstep import FleetClock, LockstepRun
from robotino_sim_node.plant_plans import PlantPlans
from robotino_sim_node.plant_realtime import RealtimeRun
from robotino_sim_node.radio import Radio
from robotino_sim_node.plant_run import RunEnd

__all__ = ["PLANT_SPECS", "JOINT_NAMES", "PlantNode", "STATUS_NAME", "main"]

STATUS_NAME = "robotino_geom_mpc: plant"

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
) + ODOMETRY_SPECS + TF_SPECS + WHEEL_PI_SPECS + LINK_SPECS + CHAIN_NODE_SPECS + ODOM_CHECK_SPECS + PAIRING_SPECS

_PLANT_DEFAULTS = {
    "mode": "realtime", "duration_s": 0.0, "physics_rate_hz": 1000.0, "command_timeout_s": 0.1, "seed": 0,
    "lockstep_resend_s": 0.5, "lockstep_max_realtime_factor": 0.0, "lockstep_settle_s": 1.0, "plans": False,
    "odometry_noise.position_m": 0.0, "odometry_noise.yaw_rad": 0.0, "timing_report": "", "timing_window_s": 0.0,
    **ODOMETRY_DEFAULTS, **TF_DEFAULTS, **WHEEL_PI_DEFAULTS, **LINK_DEFAULTS, **CHAIN_NODE_DEFAULTS,
    **ODOM_CHECK_DEFAULTS, **PAIRING_DEFAULTS,
}

_read_command = cdr_reader(Float64MultiArray, "std_msgs/msg/Float64MultiArray")  # other layouts than the controller's


class PlantNode(Node):
    """The plant simulator node (see the module docstring for its interface)."""

    def __init__(self, fleet: FleetClock | None = None, created: float | None = None, **node_options: Any) -> None:
        """`fleet`: the lockstep clock of a fleet in one process (`fleet_plant_node`; no link there), used in
        lockstep; `created`: the steady time the odometry sources' check counts its window from (a fleet's start;
        None: now); `node_options`: rclpy's `Node` options (a fleet's robot: its ``namespace``, parameter overrides).
        """
        super().__init__("robotino_plant", **node_options)
        created = monotonic() if created is None else created  # (`odom_sources`)
        self.params = SpecParameters(
            self, _all_specs(), {**spec_defaults(), **_PLANT_DEFAULTS}, self._on_params,
            # the realtime grid (steps of 1 / physics_rate_hz), the odometry model
            fixed=("mode", "physics_rate_hz", "timing_report", "plans", *ODOMETRY_DEFAULTS, *TF_DEFAULTS,
                   *WHEEL_PI_DEFAULTS, *LINK_DEFAULTS, *CHAIN_NODE_DEFAULTS, *ODOM_CHECK_DEFAULTS), check=link_problem,
        )
        p = self.params
        try:
            check_frame_prefix(p["frame_prefix"])
        except DescriptionError as exc:
            raise NodeStartError(f"parameter 'frame_prefix': {exc}") from None
        report = p["timing_report"]
        if report and not Path(report).resolve().parent.is_dir():
            raise NodeStartError(f"parameter 'timing_report': folder of {report!r} does not exist")
        self.end = RunEnd(self, report)
        lockstep, cmd_vel = p["mode"] == "lockstep", p["command_interface"] == "cmd_vel"
        chain = chain_of(p, lockstep, cmd_vel)
        self.robot_params, self.control = p.robot_control()
        noise = PoseNoise((p["odometry_noise.position_m"], p["odometry_noise.yaw_rad"]), p["seed"])
        self.robot = RobotLoop(*self._robot_parts(self.robot_params), self.control.period_s, noise,
                               lease_s=p["pairing.lease_s"])
        up, down = link_params(p.values, "up"), link_params(p.values, "down")
        # the chain takes cmd_vel as the real driver does (its own link, chain.link.*): no plans there
        follower = PlanFollower(self.control.period_s) if p["plans"] and chain is None else None
        networked = follower is not None or up.enabled or down.enabled  # else: as without a link

        qos = publish_qos(lockstep)
        self.outputs = PlantOutputs(self, qos, p, lockstep, cmd_vel, follower is not None)
        self.outputs.build(p, self.robot_params, self.control.period_s)
        self.plans = None if follower is None else PlantPlans(self.outputs, p["command_interface"], follower)
        self.command_layout = three_values_layout(VOLTAGE_LABEL)
        if self.plans is not None:  # lockstep: every answer of a tick is kept
            self.gate = SourceGate(self, self.plans.topic)
            self.command_sub = self.create_subscription(self.plans.msg_type, self.plans.topic,
                                                        WithInfo(self._on_plan), qos)
        elif cmd_vel:
            self.gate = SourceGate(self, "cmd_vel")
            self.command_sub = self.create_subscription(Twist, "cmd_vel", WithInfo(self._on_twist),
                                                        CONTROL_QOS)
        else:
            self.gate = SourceGate(self, "wheel_voltages")
            self.command_sub = self.create_subscription(Float64MultiArray, "wheel_voltages",
                                                        WithInfo(self._on_command), CONTROL_QOS, raw=True)
        self.release_srv = self.create_service(Trigger, "~/release", self._on_release)
        handshake = StartHandshake(self, self.command_sub, self.outputs.publishers())
        # nothing published and no callback run yet; the publishers match their readers meanwhile, and in lockstep
        # the start handshake settles meanwhile (tick 0 waits for the later of the two, not for their sum)
        settle = (lambda now: handshake.poll(now, p["lockstep_settle_s"])) if lockstep and chain is None else None
        check_single_odom_source(self, self.outputs.odom_pub, created, p["odom_publisher_check_s"], settle)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", PUBLISH_QOS)
        self.diag_timer = self.create_timer(1.0, self._diagnose, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.reported = (0, False)  # the refusals last reported; a release not reported yet
        self.run: LockstepRun | RealtimeRun | ChainRun
        if chain is not None:
            warm_up(self.robot.plant, 1.0 / p["physics_rate_hz"])
            self.run = ChainRun(self, p, chain, self.robot, self.outputs, self.end)
        elif lockstep:
            duration = p["duration_s"]
            ticks = LockstepTicks(self.robot, round(duration / self.control.period_s) if duration > 0 else None)
            if fleet is not None and networked:
                raise NodeStartError("a fleet's lockstep plants share one clock without a link: no link.*, no plans")
            link = CommandLink(up, down, p["seed"], follower, p["command_timeout_s"]) if networked else None
            self.run = LockstepRun(self, p, ticks, self.outputs, handshake, self.end, link, self.plans, fleet)
        else:
            warm_up(self.robot.plant, 1.0 / p["physics_rate_hz"])
            started_at = monotonic()
            grid = RealtimeGrid(self.robot, started_at, p["physics_rate_hz"], p["command_timeout_s"], follower,
                                clock_minus_steady_ns(self))  # a refused command: 0 V
            radio = Radio(self, up, down, p["seed"]) if networked else None
            self.run = RealtimeRun(self, p, grid, self.outputs, self.end, radio, self.plans)
        self.get_logger().info(f"plant simulator ready ({p['mode']}, Ts = {self.control.period_s:g} s)")

    @property
    def done(self) -> Future:
        """Set when the run is over (`ros.spin.run_node` ends the spin)."""
        return self.end.done

    @property
    def exit_status(self) -> int:
        """The process's exit status (1: the timing report could not be written)."""
        return self.end.exit_status

    # parameters ---------------------------------------------------------------------------------
    def _on_params(self, changed: dict) -> None:
        robot, self.control = self.params.robot_control()
        if robot != self.robot_params:
            self.robot_params = robot
            self.robot.rebuild(*self._robot_parts(robot, self.robot), self.control.period_s)
        self.outputs.build(self.params, robot, self.control.period_s)
        self.run.on_params()
        self.robot.set_lease(self.params["pairing.lease_s"])
        if "seed" in changed:
            self.robot.noise.reseed(self.params["seed"])

    def _robot_parts(self, robot: RobotinoParams, previous: RobotLoop | None = None
                     ) -> tuple[RobotinoPlant, OdometrySource, VoltageDrive | TwistDrive]:
        """The plant on `robot` (at `previous`'s state), its odometry (encoders continue from `previous`'s pose) and
        drive (`previous`'s wheel-speed loops). A realtime run computes the plant's matrices of every step size of
        its grid (`loop.command_hold.warm_up`: at the start here, after a change in its ``on_params``).
        """
        p = self.params
        state = None if previous is None else previous.plant.state
        plant = RobotinoPlant(robot, state0=state)
        source = odometry_source(plant, p["odometry_model"], p["encoder.counts_per_rev"], p["encoder.wheel_slip_std"],
                                 p["seed"], None if previous is None else getattr(previous.source, "pose", None))
        if p["command_interface"] != "cmd_vel":
            return plant, source, VoltageDrive(plant)
        old = None if previous is None else previous.drive_
        speed_loop = old.speed_loop if isinstance(old, TwistDrive) else \
            WheelSpeedLoop(robot, p["wheel_pi.kp"], p["wheel_pi.ki"], p["wheel_pi.rate_hz"])
        return plant, source, TwistDrive(plant, speed_loop)

    # commands -----------------------------------------------------------------------------------
    def _admit(self, info: dict[str, Any]) -> bool:
        """Whether the command (plan) of this message info comes from the paired controller (`RobotLoop.admit`)."""
        source = self.gate.source(info)
        if self.robot.admit(source, time.monotonic_ns()):
            self.gate.note(self.robot.pairing)
            return True
        self.gate.refused(self.robot.pairing, source)
        return False

    def _on_release(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/release: the next controller to command takes the robot."""
        response.success, response.message = True, self.gate.released(self.robot.pairing, self.robot.release())
        self.reported = (self.reported[0], True)
        return response

    def _diagnose(self) -> None:
        """The pairing's status, when there is news: refusals since the last one, or a hand-over after a release."""
        pairing = self.robot.pairing
        refused = pairing.refused_total
        handed_over = self.reported[1] and pairing.holder is not None
        if refused == self.reported[0] and not handed_over:
            return
        self.reported = (refused, self.reported[1] and not handed_over)
        status = DiagnosticStatus(name=STATUS_NAME, hardware_id="robotino",
                                  level=DiagnosticStatus.WARN if refused else DiagnosticStatus.OK,
                                  message=f"second source refused: {self.gate.intruders}" if refused else
                                  "one source" if pairing.holder is not None else "no commands yet")
        values = {**self.gate.status(pairing), **{k: str(v) for k, v in self.robot.counts.items()}}
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(msg)

    def _on_command(self, data: bytes, info: dict[str, Any]) -> None:
        if not self._admit(info):
            return
        values = self.command_layout.read(data)  # the controller's layout, read in place; else decoded
        if values is None:
            try:
                values = tuple(_read_command(data).data)
            except MalformedMessage:
                values = ()
        self._apply(values)

    def _on_twist(self, msg: Twist, info: dict[str, Any]) -> None:
        if self._admit(info):
            self._apply((msg.linear.x, msg.linear.y, msg.angular.z))

    def _apply(self, values: tuple[float, ...]) -> None:
        self.run.command(values)  # checked by the run (the chain forwards only valid ones)

    def _on_plan(self, msg: Any, info: dict[str, Any]) -> None:
        # (the chain subscribes to cmd_vel, never to plans)
        if not isinstance(self.run, ChainRun) and self._admit(info):
            self.run.plan(msg)


def _all_specs() -> tuple[ParamSpec, ...]:
    from robotino_geom_mpc.params.specs import ALL_SPECS
    return ALL_SPECS + PLANT_SPECS


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc plant_node``."""
    return run_node(PlantNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
