"""The plant node as the real Robotino's driver + firmware on DDS (``chain.active`` on; realtime only).

With ``chain.active: enabled`` the plant node (`plant_node.PlantNode`) runs `ChainRun` instead of its realtime
run: the plant behind `model.chain_emulation.ChainEmulator` (polled by `loop.chain_robot.ChainRobot`) in real
time (the PI loops sampled at ``wheel_pi.rate_hz``): the firmware's 20 ms tick with its ramps, maxima and motor
timeout, odometry sampled at ``chain.odometry_rate_hz`` without a stamp, the driver's loop at
``chain.driver_rate_hz`` that dispatches it on ``odom`` stamped with the pass's time and forwards each
``cmd_vel`` once (speed floor), the link ``chain.link.*`` between them, and the wheels' PI loops
(``chain.speed_loop_time_constant_s``). The emulation's time t is the steady time since the node's first poll
(not its construction: the passes due while it started would come out in one burst); a stamp is the node clock
then plus t. A timer every ``_POLL_S`` runs the emulation up to now and publishes what the driver dispatched;
each pass also publishes ``ground_truth/odom`` (the true pose at the plant's time, stamped with it),
``wheel_currents`` (the signed peaks over the ticks since the last), ``applied_voltages`` (their PI
voltages' mean) and the joint states, as the plant does per period. After ``duration_s`` it writes the
timing report (the plant's keys, ``mode`` "chain") and ends the run.
"""

from __future__ import annotations

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from robotino_geom_mpc.loop.chain_robot import LATE_S, ChainRobot
from robotino_geom_mpc.loop.command_hold import warm_up
from robotino_geom_mpc.loop.robot_loop import RobotLoop
from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import CHAIN_NODE_DEFAULTS, CHAIN_NODE_SPECS, ChainError, ChainParams, \
    chain_params
from robotino_geom_mpc.params.specs import CHAIN_ACTIVE_SPEC
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters
from robotino_geom_mpc.ros.spin import monotonic
from robotino_geom_mpc.ros.throttle import warn_throttled
from robotino_sim_node.outputs import PlantOutputs
from robotino_sim_node.plant_run import RunEnd, emit

__all__ = ["CHAIN_NODE_DEFAULTS", "CHAIN_NODE_SPECS", "ChainRun", "chain_of"]  # the specs for the node

_POLL_S = 0.005


def chain_of(params: SpecParameters, lockstep: bool, cmd_vel: bool) -> ChainParams | None:
    """The chain of the node's ``chain.*`` when ``chain.active`` is on, else None; NodeStartError for a lockstep or
    voltage plant or a bad ``chain.*`` value (named).
    """
    if params[CHAIN_ACTIVE_SPEC.name] != "enabled":
        return None
    if lockstep or not cmd_vel:
        raise NodeStartError("chain.active enabled needs mode realtime and command_interface cmd_vel (the driver's "
                             "loop and the firmware's tick run on the wall clock; the driver takes cmd_vel)")
    try:
        return chain_params({name: params[name] for name in CHAIN_NODE_DEFAULTS if name != CHAIN_ACTIVE_SPEC.name},
                            where="the plant's parameters")
    except ChainError as exc:
        raise NodeStartError(str(exc)) from None


class ChainRun:
    """The driver + firmware chain in front of the plant node's plant (module docstring).

    Parameters
    ----------
    node
        The plant node (its clock, timers, logger).
    params
        Its parameters (``seed``, ``odometry_noise.*``, ``wheel_pi.rate_hz``, ``duration_s``).
    chain
        The chain.
    robot
        The robot loop (its plant runs behind the chain; its counts go into the report).
    outputs
        The publishers.
    end
        The run's end.
    """

    def __init__(self, node: Node, params: SpecParameters, chain: ChainParams, robot: RobotLoop,
                 outputs: PlantOutputs, end: RunEnd) -> None:
        self.node, self.params, self.chain, self.robot = node, params, chain, robot
        self.outputs, self.end = outputs, end
        robot.plant.reset(robot.plant.state)
        self.emulated = ChainRobot(ChainEmulator(
            robot.plant, chain, seed=params["seed"],
            odometry_noise=(params["odometry_noise.position_m"], params["odometry_noise.yaw_rad"]),
            speed_loop_rate_hz=params["wheel_pi.rate_hz"]))
        self.late = 0  # driver passes run more than LATE_S after their time (the host could not keep up)
        self.busy_s = 0.0
        self.timer = node.create_timer(_POLL_S, self._poll, clock=Clock(clock_type=ClockType.STEADY_TIME))
        node.get_logger().info(f"plant behind the driver chain: odometry {chain.odometry_rate_hz:g} Hz stamped "
                               f"on dispatch by a {chain.driver_rate_hz:g} Hz loop, {1e3 * chain.tick_s:g} ms "
                               f"firmware tick, link delay {1e3 * chain.link_delay_s:g} ms")

    def on_params(self) -> None:
        """After a parameter change: the plant's matrices of every step size of the ``physics_rate_hz`` grid."""
        warm_up(self.robot.plant, 1.0 / self.params["physics_rate_hz"])

    def command(self, values: tuple[float, ...]) -> None:
        """A cmd_vel: refused (not forwarded) unless three finite values; forwarded to the driver now."""
        refused = self.emulated.command(values, monotonic())
        if refused is not None:
            self.robot.counts["refused_commands"] += 1
            emit(self.node, [refused])

    def _poll(self) -> None:
        begin = monotonic()
        duration = self.params["duration_s"]
        if duration > 0.0 and self.emulated.elapsed_s(begin, self.node.get_clock().now().nanoseconds) >= duration:
            self._finish(begin)
            return
        outputs = self.outputs
        for chain_pass in self.emulated.poll(begin, self.node.get_clock().now().nanoseconds):
            if chain_pass.late_s > LATE_S:
                self.late += 1
                warn_throttled(self.node.get_logger(), f"the emulated chain runs {chain_pass.late_s:.3f} s behind "
                               f"the wall clock ({self.late} late passes): the host is too slow for wheel_pi.rate_hz",
                               1.0)
            outputs.publish([outputs.odometry(m) for m in chain_pass.odometry])
            state = chain_pass.state
            if state is not None:  # ground truth, currents, voltages and joints of the ticks since the last pass
                outputs.publish(outputs.period(state.currents, state.applied_voltages) + outputs.state(
                    state.stamp_ns, self.robot, tuple(self.robot.plant.pose)))
        self.busy_s += monotonic() - begin

    def _finish(self, now: float) -> None:
        self.timer.cancel()
        emulated, emulator = self.emulated, self.emulated.emulator
        simulated = emulator.time_s
        wall = now - (emulated.started_at or now)
        self.node.get_logger().info(f"chain run over: {simulated:.3g} s emulated in {wall:.3g} s, "
                                    f"{emulated.dispatched} odometry messages dispatched, {emulated.commands} cmd_vel "
                                    f"received, {len(emulator.forwarded)} forwarded")
        self.end.finish({"mode": "chain", "ticks": len(emulator.trace), "simulated_s": simulated, "wall_s": wall,
                         "realtime_factor": simulated / wall if wall > 0 else None,
                         "odometry_dispatched": emulated.dispatched, "cmd_vel_received": emulated.commands,
                         "cmd_vel_forwarded": len(emulator.forwarded), "late_passes": self.late,
                         **self.robot.counts})
