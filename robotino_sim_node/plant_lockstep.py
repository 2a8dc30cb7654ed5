"""The lockstep plant's run: the start handshake, the ticks (over the emulated link or not), resends, pace, report.

The plant owns time (`loop.robot_loop.LockstepTicks`): tick k is the state at t_k = k Ts; it publishes the
odometry (then /clock and the other measurements of tick k), waits for the command of tick k, integrates one
control period with it and publishes tick k + 1 (not before its slot if ``lockstep_max_realtime_factor`` > 0).
The current tick is published again after ``lockstep_resend_s`` without an answer.

Over the emulated link (``link.*`` or ``plans``; `loop.command_link.CommandLink`, sim time), each tick k in the
order of `offline.networked`, so that the DDS loop reproduces the offline loop with the same link:

1. /clock (not over the link: it is the simulation's time), then the tick's messages as one radio packet (the
   ``command_applied`` reports since the last packet, odom, the currents, the ground truth, joint_states, /tf)
   sent up at t_k; the packets due by t_k are published in order, each with its reports first (the controller
   takes them before the odometry). The controller answers each odometry newer than every one before it
   (`loop.link_queue.RobotLink.answers_due`); with none due the plant goes on at once (a lost or late odometry:
   no answer is waited for).
2. each answer (a plan, or a plain command) is sent down at t_k; once all are there:
3. the packets due down by t_k: plans offered to the buffer at t_k, or the last plain command held (zero after
   ``command_timeout_s``, the drive's watchdog);
4. the period's command: the plans' entry (reported), or the held command; one period integrated.

A resend sends /clock and the odometries delivered at the tick again (the controller answers an odometry once).

A fleet (`robotino_sim_node.fleet_plant_node`: N plants in one process, no link) shares one `FleetClock`: a robot's
next tick is held until every robot's is due, then each robot's odometry and measurements go out and one /clock
after them, so tick k is the same instant for the whole fleet.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from robotino_geom_mpc.loop.command_link import CommandLink
from robotino_geom_mpc.loop.robot_loop import LockstepTicks, Measurement
from robotino_geom_mpc.ros.parameters import SpecParameters
from robotino_geom_mpc.ros.spin import monotonic
from robotino_geom_mpc.ros.throttle import warn_throttled
from robotino_sim_node.lockstep_start import StartHandshake
from robotino_sim_node.loop_timing import LockstepPace, lockstep_line, lockstep_report
from robotino_sim_node.outputs import Message, PlantOutputs
from robotino_sim_node.plant_plans import PlantPlans
from robotino_sim_node.plant_run import RunEnd, checked_command, emit

__all__ = ["FleetClock", "LockstepRun"]


class LockstepRun:
    """The lockstep plant's run (module docstring).

    Parameters
    ----------
    node
        The plant node (timers, logger).
    params
        Its parameters (``lockstep_*``).
    ticks
        The robot loop's lockstep time.
    outputs
        The publishers.
    handshake
        When tick 0 may go out.
    end
        The run's end.
    link
        The emulated link (None: the commands apply directly).
    plans
        The plan messages' adapter (with plans).
    fleet
        The fleet's clock (a fleet of plants in one process; without a link), None: this run's own /clock.
    """

    def __init__(self, node: Node, params: SpecParameters, ticks: LockstepTicks, outputs: PlantOutputs,
                 handshake: StartHandshake, end: RunEnd, link: CommandLink | None = None,
                 plans: PlantPlans | None = None, fleet: FleetClock | None = None) -> None:
        self.node, self.params, self.ticks, self.robot, self.outputs = node, params, ticks, ticks.robot, outputs
        self.handshake, self.end, self.link, self.plans = handshake, end, link, plans
        self.fleet = fleet
        self.held = False  # a fleet's: the next tick waits for the other robots' (no resend meanwhile)
        if fleet is not None:
            fleet.join(self)
        self.pace = LockstepPace(self.params["lockstep_max_realtime_factor"], self.robot.period_s)
        self.measurement: Measurement | None = None  # of the current tick (a resend sends its odometry again)
        self.delivered: list[tuple[int, list[Message]]] = []  # over the link: this tick's packets (stamp, messages)
        self.expected = self.answers = 0  # over the link: answers due this tick, received
        self.started = False
        self.busy_s = self.wait_s = 0.0  # in the callbacks; waiting for commands (ticks 1 ..)
        self.resent = 0
        self.published_at = self.tick_sent_at = self.started_at = self.first_answer_at = monotonic()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.pace_timer = node.create_timer(1.0, self._paced_tick, clock=steady, autostart=False)  # per held tick
        self.start_timer = node.create_timer(0.01, self._try_start, clock=steady)
        self.resend_timer = node.create_timer(self.params["lockstep_resend_s"] / 2, self._resend, clock=steady)

    def on_params(self) -> None:
        """The pace after a parameter change."""
        self.pace = LockstepPace(self.params["lockstep_max_realtime_factor"], self.robot.period_s)

    # the commands -------------------------------------------------------------------------------------------
    def command(self, values: Sequence[float]) -> None:
        """A command of the controller (voltages or twist) for the current tick, checked (`checked_command`)."""
        self.answer(tuple(checked_command(self.node, self.robot, values)[0]))

    def plan(self, msg: Any) -> None:
        """A plan message: read, then over the link like any answer."""
        assert self.plans is not None
        self.answer(self.plans.read(msg))

    def answer(self, item: Any) -> None:
        """The controller's answer to the current tick: its period (directly), or sent down the link."""
        if not self.started or self.end.done.done():
            return
        begin = monotonic()
        if self.link is None:
            if self._period(item):
                self._tick_due()
        elif self.answers < self.expected:  # else none is due (a repeat)
            self.link.send_down(self.ticks.time_s, item)
            self.answers += 1
            if self.answers == self.expected and self._network_step():
                self._network_run()
        self.busy_s += monotonic() - begin

    # the ticks ------------------------------------------------------------------------------------------------
    def _try_start(self) -> None:
        now = monotonic()
        if self.handshake.poll(now, self.params["lockstep_settle_s"]):
            self.start_timer.cancel()
            self.started = True
            self.started_at = now
            self._tick_due()

    def _resend(self) -> None:
        now = monotonic()
        if self.started and not self.end.done.done() and self.pace_timer.is_canceled() and not self.held \
                and now - self.published_at > self.params["lockstep_resend_s"]:
            self.resent += 1
            warn_throttled(self.node.get_logger(), f"no command for tick {self.ticks.tick} (t = "
                           f"{self.ticks.time_s:.3f} s) for {now - self.tick_sent_at:.1f} s: resending "
                           f"({self.resent} resends so far)", 2.0)
            self._publish_tick(fresh=False)

    def _paced_tick(self) -> None:  # the tick `lockstep_max_realtime_factor` held back, at its slot
        self.pace_timer.cancel()
        self._tick_due()

    def _tick_due(self) -> None:
        """The next tick may go out: now, or in a fleet once every robot's may (`FleetClock.due`)."""
        if self.fleet is None:
            self._publish_tick(fresh=True)
        else:
            self.held = True
            self.fleet.due(self)

    def publish_held(self) -> None:
        """A fleet's: publish the held tick (its odometry and measurements; the fleet sends /clock)."""
        self.held = False
        self._publish_tick(fresh=True)

    def _publish_tick(self, fresh: bool) -> None:
        """Odometry first (the controller's critical path), then /clock, the currents and the rest (`fresh`: a new
        tick; else the current tick's odometry and /clock again).
        """
        if self.link is not None:
            if fresh:
                self._network_run()
            else:
                self._network_tick(fresh=False)
            return
        if fresh or self.measurement is None:
            self.measurement = self.ticks.measurement()
            self.outputs.publish(self.outputs.tick(self.measurement, self.robot, clock=self.fleet is None))
        else:
            self.outputs.publish([self.outputs.odometry(self.measurement), self.outputs.clock(self.ticks.time_ns)])
        self.published_at = monotonic()
        if fresh:
            self.tick_sent_at = self.published_at

    def _period(self, values: Sequence[float]) -> bool:
        """Integrate the tick's period under `values` and go to the next tick; True: publish it now (else the pace
        holds it back, or the run is over).
        """
        begin = monotonic()
        self.wait_s += begin - self.published_at
        if self.ticks.tick == 0:
            self.first_answer_at = begin
            self.busy_s = self.wait_s = 0.0  # per-tick figures of the running loop (ticks 1 ..)
        if not self.ticks.period(values):
            self._finish(begin)
            return False
        delay = self.pace.delay(monotonic())
        if delay > 0.0:
            self.pace_timer.timer_period_ns = max(1, int(delay * 1e9))
            self.pace_timer.reset()
            return False
        return True

    def _finish(self, last_answer_at: float) -> None:
        """The last tick is answered: the currents of the last period (no tick follows) and what it applied, the
        run's real-time factor (ticks 1 .. n - 1, from the answer of tick 0 to that of the last), the end.
        """
        currents, voltages = self.robot.account.take(self.robot.plant)
        self.outputs.publish(self.outputs.period(currents, voltages) + self._reports())
        report = lockstep_report(self.ticks.tick + 1, self.robot.period_s, self.started_at, self.first_answer_at,
                                 last_answer_at, self.busy_s, self.wait_s, resent=self.resent, **self.robot.counts)
        self.node.get_logger().info(lockstep_line(report))
        self.end.finish(report)

    def _reports(self) -> list[Message]:
        return [] if self.plans is None or self.link is None else self.plans.messages(self.link.pop_reports())

    # over the link ---------------------------------------------------------------------------------------------
    def _network_tick(self, fresh: bool) -> None:
        """Step 1: /clock, the tick's packet up, the packets due published; the answers due counted (resent: /clock
        and the odometries delivered this tick again).
        """
        assert self.link is not None
        t_ns = self.ticks.time_ns
        self.outputs.publish([self.outputs.clock(t_ns)])
        self.published_at = monotonic()
        if not fresh:
            self.outputs.publish([(pub, data) for _, bundle in self.delivered for pub, data in bundle
                                  if pub is self.outputs.odom_pub])
            return
        self.tick_sent_at = self.published_at
        reports = self._reports()
        self.measurement = self.ticks.measurement()
        self.delivered = self.link.send_up(self.ticks.time_s, (t_ns, reports + self.outputs.tick(self.measurement,
                                                                                               self.robot)))
        self.expected, self.answers = self.link.link.answers_due([s for s, _ in self.delivered]), 0
        for _, bundle in self.delivered:
            self.outputs.publish(bundle)

    def _network_run(self) -> None:
        """Publish ticks until one has an answer due (or the pace holds the next back, or the run ends)."""
        while True:
            self._network_tick(fresh=True)
            if self.expected or not self._network_step():
                return

    def _network_step(self) -> bool:
        """Steps 3-4: the packets due down taken, the period's command, one period; True: next tick now."""
        assert self.link is not None
        t = self.ticks.time_s
        for item, reason in self.link.take_due(t):
            if self.plans is not None:
                emit(self.node, self.plans.refusal(item, reason))
        return self._period(self.link.period_command(t))


class FleetClock:
    """One /clock for the lockstep runs of a fleet in one process: a tick goes out when every robot's is due.

    Each run calls `due` when its next tick may go out (tick 0 after its start handshake, then after its answer
    and pace); once every run has, each publishes its tick (`LockstepRun.publish_held`: odometry first) and the
    first run's /clock publisher sends the tick's time once. The runs share the period and the run length
    (`fleet_plant_node` checks), so their ticks are the same instants.
    """

    def __init__(self) -> None:
        self.runs: list[LockstepRun] = []
        self.waiting = 0  # runs whose next tick is due

    def join(self, run: LockstepRun) -> None:
        """`run` is one of the fleet's."""
        self.runs.append(run)

    def due(self, run: LockstepRun) -> None:
        """`run`'s next tick may go out (it holds it: `LockstepRun.held`); the last one due sends them all."""
        self.waiting += 1
        if self.waiting < len(self.runs):
            return
        self.waiting = 0
        for each in self.runs:
            each.publish_held()
        first = self.runs[0]
        first.outputs.publish([first.outputs.clock(first.ticks.time_ns)])
