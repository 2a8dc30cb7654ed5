"""The plant node as the real Robotino's driver + firmware on DDS (``chain.active`` on; realtime only).

With ``chain.active: enabled`` the plant node (`plant_node.PlantNode`) hands its command input and its
measurement timer over to `ChainDriver`, which runs the plant behind `model.chain_emulation.ChainEmulator`
in real time (the PI loops sampled at ``wheel_pi.rate_hz``): the firmware's 20 ms tick with its ramps, maxima
and motor timeout, odometry sampled at
``chain.odometry_rate_hz`` without a stamp, the driver's loop at ``chain.driver_rate_hz`` that dispatches
it on ``odom`` stamped with the pass's time and forwards each ``cmd_vel`` once (speed floor), the link
``chain.link.*`` between them, and the wheels' PI loops (``chain.speed_loop_time_constant_s``). The
emulation's time t is the steady time since the node's first poll (not its construction: the passes due
while it started would come out in one burst); a stamp is the node clock then plus t. A timer every ``_POLL_S``
runs the emulation up to now and publishes what the driver dispatched;
each pass also publishes ``ground_truth/odom`` (the true pose at the plant's time, stamped with it),
``wheel_currents`` (the signed peaks over the ticks since the last), ``applied_voltages`` (their PI
voltages' mean) and the joint states, as the plant does per period. After ``duration_s`` it writes the
timing report (the plant's keys, ``mode`` "chain") and ends the run.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from geometry_msgs.msg import Twist
from rclpy.clock import Clock, ClockType

from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import CHAIN_NODE_DEFAULTS, CHAIN_NODE_SPECS, ChainError, chain_params
from robotino_geom_mpc.params.specs import CHAIN_ACTIVE_SPEC
from robotino_geom_mpc.ros.parameters import NodeStartError
from robotino_geom_mpc.ros.qos import CONTROL_QOS, publish_acknowledged
from robotino_geom_mpc.ros.spin import monotonic
from robotino_sim_node.outputs import odometry_values
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["CHAIN_NODE_DEFAULTS", "CHAIN_NODE_SPECS", "ChainDriver", "attach_chain"]  # the specs for the node

_POLL_S = 0.005
_LATE_S = 0.05


def attach_chain(node: Any) -> ChainDriver | None:
    """A `ChainDriver` on `node` (a `PlantNode`) when its ``chain.active`` is on, else None; NodeStartError
    for a lockstep or voltage plant or a bad ``chain.*`` value (named).
    """
    if node.params[CHAIN_ACTIVE_SPEC.name] != "enabled":
        return None
    if node.lockstep or node.speed_loop is None:
        raise NodeStartError("chain.active enabled needs mode realtime and command_interface cmd_vel (the driver's "
                             "loop and the firmware's tick run on the wall clock; the driver takes cmd_vel)")
    return ChainDriver(node)


class ChainDriver:
    """The driver + firmware chain in front of the plant node's plant (module docstring)."""

    def __init__(self, node: Any) -> None:
        try:
            self.chain = chain_params({name: node.params[name] for name in CHAIN_NODE_DEFAULTS
                                       if name != CHAIN_ACTIVE_SPEC.name}, where="the plant's parameters")
        except ChainError as exc:
            raise NodeStartError(str(exc)) from None
        self.node = node
        node.publish_timer.cancel()  # the plant's own measurements and command input are the chain's now
        node.destroy_subscription(node.command_sub)
        p = node.params
        node.plant.reset(node.plant.state)
        self.emulator = ChainEmulator(node.plant, self.chain, seed=p["seed"],
                                      odometry_noise=(p["odometry_noise.position_m"], p["odometry_noise.yaw_rad"]),
                                      speed_loop_rate_hz=p["wheel_pi.rate_hz"])
        self.late = 0  # driver passes run more than _LATE_S after their time (the host could not keep up)
        self.started_at: float | None = None  # the first poll: no burst of passes piled up while the node started
        self.start_ns = 0
        self.published_ticks = 0
        self.dispatched = 0
        self.commands = 0
        node.command_sub = node.create_subscription(Twist, "cmd_vel", self._on_twist, CONTROL_QOS)
        self.timer = node.create_timer(_POLL_S, self._poll, clock=Clock(clock_type=ClockType.STEADY_TIME))
        node.get_logger().info(f"plant behind the driver chain: odometry {self.chain.odometry_rate_hz:g} Hz stamped "
                               f"on dispatch by a {self.chain.driver_rate_hz:g} Hz loop, "
                               f"{1e3 * self.chain.tick_s:g} ms "
                               f"firmware tick, link delay {1e3 * self.chain.link_delay_s:g} ms")

    def _stamp(self, t: float) -> tuple[int, int]:
        return divmod(self.start_ns + int(round(t * 1e9)), 1_000_000_000)

    def _on_twist(self, msg: Twist) -> None:
        values = (msg.linear.x, msg.linear.y, msg.angular.z)
        if not math.isfinite(sum(values)):
            self.node.counts["refused_commands"] += 1
            warn_throttled(self.node.get_logger(), f"refused cmd_vel {values}: not forwarded", 1.0)
            return
        if self.started_at is None:
            return  # before the chain's first instant: nothing to forward it to yet
        self.commands += 1
        self.emulator.cmd_vel(values, max(monotonic() - self.started_at, self.emulator.time_s))

    def _poll(self) -> None:
        node, emulator = self.node, self.emulator
        begin = monotonic()
        if self.started_at is None:
            self.started_at, self.start_ns = begin, node.get_clock().now().nanoseconds
        now = begin - self.started_at
        duration = node.params["duration_s"]
        if duration > 0.0 and now >= duration:
            self._finish(begin)
            return
        while emulator.next_pass_s() <= now:
            t_pass = emulator.next_pass_s()
            if now - t_pass > _LATE_S:
                self.late += 1
                warn_throttled(node.get_logger(), f"the emulated chain runs {now - t_pass:.3f} s behind the wall clock "
                                       f"({self.late} late passes): the host is too slow for wheel_pi.rate_hz", 1.0)
            for message in emulator.run_until(t_pass):
                publish_acknowledged(node, node.odom_pub, node.odom_cdr.pack(*self._stamp(message.stamp_s),
                                                                              *odometry_values(message.pose,
                                                                                               message.twist)))
                self.dispatched += 1
            self._publish_state()
        node.busy_s += monotonic() - begin

    def _publish_state(self) -> None:
        """Ground truth, currents, voltages and joints of the ticks run since the last pass."""
        node, emulator = self.node, self.emulator
        ticks = emulator.trace[self.published_ticks:]
        if not ticks:
            return
        self.published_ticks = len(emulator.trace)
        currents = np.array([r.currents for r in ticks])
        peak = np.abs(currents).max(axis=0)
        node.peak_currents = peak
        node.applied.volt_seconds = np.array([r.voltages for r in ticks]).sum(axis=0) * self.chain.tick_s
        node.applied.seconds = len(ticks) * self.chain.tick_s
        stamp = self._stamp(node.plant.time_s)
        if node.truth_pub.get_subscription_count():
            publish_acknowledged(node, node.truth_pub,
                                 node.truth_cdr.pack(*stamp, *odometry_values(*node.plant.odometry_floats())))
        node._publish_currents()
        plant = node.plant
        node.state_out.publish(stamp, tuple(plant.pose_floats()), plant.wheel_angles.tolist(),
                               plant.wheel_speeds.tolist(), (node.effort_per_a * plant.currents).tolist())

    def _finish(self, now: float) -> None:
        node = self.node
        self.timer.cancel()
        simulated = self.emulator.time_s
        wall = now - self.started_at
        node.get_logger().info(f"chain run over: {simulated:.3g} s emulated in {wall:.3g} s, "
                               f"{self.dispatched} odometry messages dispatched, {self.commands} cmd_vel received, "
                               f"{len(self.emulator.forwarded)} forwarded")
        node._write_report({"mode": "chain", "ticks": len(self.emulator.trace), "simulated_s": simulated,
                            "wall_s": wall, "realtime_factor": simulated / wall if wall > 0 else None,
                            "odometry_dispatched": self.dispatched, "cmd_vel_received": self.commands,
                            "cmd_vel_forwarded": len(self.emulator.forwarded), "late_passes": self.late,
                            **node.counts})
        node.done.set_result(True)
