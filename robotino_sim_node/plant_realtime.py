"""The realtime plant's run: the plant on the steady clock's grid (`loop.robot_loop.RealtimeGrid`), measured.

Each command and each publish first integrates the plant up to the last grid point before now with the command
held so far (zero volts once that command is older than ``command_timeout_s``, as a real drive's watchdog does; a
throttled warning, ``command_timeouts`` in the report), then applies the new command or sends the measurements.
So there is no physics timer (nothing wakes the process between events) and a command takes effect at most one
grid step late. A publish timer sends the measurements every control period, stamped with the node-clock time of
the grid point they belong to, once per grid point; after ``duration_s`` (if > 0) the node reports the loop's
timing as it saw it (`loop_timing.LoopTiming`) and exits.

Over the emulated link (`radio.Radio`, the node clock): each publish's messages leave as one packet when the link
delivers it (stamped with the grid point's robot time: steady time + the clock offset taken at the start, the
plans' reports first); a command or plan is taken when the link delivers it; the plans' entries apply from their
times on the integration grid (one per control period, chosen at its start).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from robotino_geom_mpc.loop.command_hold import warm_up
from robotino_geom_mpc.loop.plan_follower import Unreadable
from robotino_geom_mpc.loop.robot_loop import RealtimeGrid
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.ros.parameters import SpecParameters
from robotino_geom_mpc.ros.spin import monotonic
from robotino_sim_node.loop_timing import LoopTiming, clock_minus_steady_ns, realtime_report
from robotino_sim_node.outputs import Message, PlantOutputs
from robotino_sim_node.plant_plans import PlantPlans
from robotino_sim_node.radio import Radio
from robotino_sim_node.plant_run import RunEnd, checked_command, emit

__all__ = ["RealtimeRun"]


class RealtimeRun:
    """The realtime plant's run (module docstring).

    Parameters
    ----------
    node
        The plant node (its clock, timers, logger).
    params
        Its parameters (``duration_s``, ``timing_window_s``).
    grid
        The robot loop's realtime time (its origin the steady time at the start).
    outputs
        The publishers.
    end
        The run's end.
    radio
        The emulated link (None: messages and commands go at once).
    plans
        The plan messages' adapter (with plans).
    """

    def __init__(self, node: Node, params: SpecParameters, grid: RealtimeGrid, outputs: PlantOutputs, end: RunEnd,
                 radio: Radio | None = None, plans: PlantPlans | None = None) -> None:
        self.node, self.params, self.grid, self.robot = node, params, grid, grid.robot
        self.outputs, self.end, self.radio, self.plans = outputs, end, radio, plans
        self.ticks = 0  # published
        self.busy_s = 0.0
        self.timing = LoopTiming(window_s=params["timing_window_s"])
        self.publish_timer = node.create_timer(self.robot.period_s, self._publish,
                                               clock=Clock(clock_type=ClockType.STEADY_TIME))

    def on_params(self) -> None:
        """After a parameter change: the (new) plant's matrices of every step size of the grid computed now."""
        warm_up(self.robot.plant, self.grid.hold.dt)

    def command(self, command: Sequence[float]) -> None:
        """A command (voltages or twist), checked (`checked_command`), taken when the link delivers it."""
        values, valid = checked_command(self.node, self.robot, command)
        if self.radio is None:
            self._hold(values, valid)
        else:
            self.radio.send("down", lambda: self._hold(values, valid))

    def plan(self, msg: Any) -> None:
        """A plan message, taken when the link delivers it."""
        assert self.plans is not None and self.radio is not None
        plan = self.plans.read(msg)
        self.radio.send("down", lambda: self._take_plan(plan))

    def _hold(self, values: Sequence[float], valid: bool) -> None:
        begin = monotonic()
        if valid:
            self.timing.command(begin)
        emit(self.node, self.grid.hold_command(values, begin))
        self.busy_s += monotonic() - begin

    def _take_plan(self, plan: CommandPlan | Unreadable) -> None:
        assert self.plans is not None
        begin = monotonic()
        reason, logs = self.grid.take_plan(plan, begin)
        emit(self.node, logs + self.plans.refusal(plan, reason))
        if reason is None:
            self.timing.command(begin)
        self.busy_s += monotonic() - begin

    def _publish(self) -> None:
        now = monotonic()
        duration = self.params["duration_s"]
        if duration > 0.0 and now - self.grid.started_at >= duration:
            self._finish(now)
            return
        # the radio: the robot clock taken at the start; else the node clock read now
        offset_ns = self.grid.offset_ns if self.radio is not None else clock_minus_steady_ns(self.node)
        measurement, logs = self.grid.measure(now, offset_ns)
        emit(self.node, logs)
        if measurement is None:  # a late timer firing again: no new state
            return
        self.timing.published(monotonic())
        messages = self.outputs.tick(measurement, self.robot)
        if self.radio is not None:  # the tick's packet (the reports first) leaves over the link
            bundle: list[Message] = self._reports() + messages
            self.radio.send("up", lambda: self.outputs.publish(bundle), measurement.stamp_s)
        else:
            self.outputs.publish(messages)
        self.ticks += 1
        self.busy_s += monotonic() - now

    def _reports(self) -> list[Message]:
        return [] if self.plans is None else self.plans.messages(self.plans.follower.pop_reports())

    def _finish(self, now: float) -> None:
        counts = self.robot.counts
        self.node.get_logger().info(f"realtime run over: {self.timing.summary()}; {counts['clamped_commands']} "
                                    f"commands clamped, {counts['refused_commands']} refused, "
                                    f"{counts['command_timeouts']} timed out")
        self.publish_timer.cancel()
        self.end.finish(realtime_report(self.timing, self.ticks, self.grid.simulated_s, now - self.grid.started_at,
                                        self.busy_s, **counts))
