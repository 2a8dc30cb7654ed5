"""The plant node's networked side: its emulated radio link and the plans (`plant_node` with a link or ``plans``).

`PlantNetwork` is a part of `plant_node.PlantNode` (a mixin: its methods use the node's publishers, plant and
counters). What it does, per mode:

``lockstep`` (`loop.link_queue.RobotLink`, sim time), each tick k in the order of `offline.networked`, so that
the DDS loop reproduces the offline loop with the same link:

1. /clock (not over the link: it is the simulation's time), then the tick's messages as one radio packet
   (`_measure_bundle`: the ``command_applied`` reports since the last packet, odom, the currents, the ground
   truth, joint_states, /tf) sent up at t_k; the packets due by t_k are published in order, each with its
   reports first (the controller takes them before the odometry, as the offline controller does; a report that
   comes after an odometry still waiting for its preview it holds back, `controller_plans`). The controller
   answers each odometry newer than every one before it (`RobotLink.answers_due`); with none due the plant goes
   on at once (a lost or late odometry: no answer is waited for).
2. each answer (a plan, or a plain command) is sent down at t_k; once all are there:
3. the packets due down by t_k: plans offered to the buffer at t_k (`plant_plans`), or the last plain command held
   (zero after ``command_timeout_s``, the drive's watchdog);
4. the period's command: `PlanBuffer.command_at(t_k)` (reported), or the held command; one period integrated.

A tick whose answers do not come within ``lockstep_resend_s`` sends /clock and the odometries delivered at it
again (the controller answers an odometry once).

``realtime`` (`radio.Radio`, the node clock): each publish's messages leave as one packet when the link delivers
it (stamped with the grid point's robot time: steady time + the clock offset taken at the start); a command or
plan is taken when the link delivers it; the plans' entries apply from their times on the integration grid.
"""

from __future__ import annotations

import numpy as np

from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S
from robotino_geom_mpc.ros.qos import publish_acknowledged
from robotino_geom_mpc.ros.spin import monotonic
from robotino_geom_mpc.loop.command_hold import MAX_CHUNK

__all__ = ["PlantNetwork"]


class PlantNetwork:
    """The networked methods of the plant node (see the module docstring)."""

    def _send(self, pub, data) -> None:
        """A measurement of the tick: into its radio packet (while one is built), else out now."""
        if self.bundle is not None:
            self.bundle.append((pub, data))
        else:
            publish_acknowledged(self, pub, data)

    def _measure_bundle(self, stamp: tuple[int, int]) -> list:
        """The tick's messages as one radio packet: the reports since the last one, then the measurements."""
        self.bundle = [] if self.plans is None else [(self.applied_pub, m) for m in self.plans.pop_reports()]
        self._publish_measurements(stamp, fresh=True)
        bundle, self.bundle = self.bundle, None
        return bundle

    def _publish_bundle(self, bundle: list) -> None:
        """A delivered packet, in order: the reports, then the measurements (the controller takes the reports
        before the odometry).
        """
        for pub, data in bundle:
            publish_acknowledged(self, pub, data)

    def _network_tick(self, fresh: bool) -> None:
        """Lockstep step 1 (`offline.networked`): /clock, the tick's packet up, the packets due published; the
        answers due counted (`RobotLink.answers_due`; resent: /clock and the odometries delivered this tick again).
        """
        t_ns = self._time_ns()
        stamp = divmod(t_ns, 1_000_000_000)
        publish_acknowledged(self, self.clock_pub, self.clock_cdr.pack(*stamp))
        self.published_at = monotonic()
        if not fresh:
            for _, bundle in self.delivered:
                for pub, data in bundle:
                    if pub is self.odom_pub:
                        publish_acknowledged(self, pub, data)
            return
        self.tick_sent_at = self.published_at
        self.sim_link.up.send(t_ns * 1e-9, (t_ns, self._measure_bundle(stamp)))
        self.delivered = self.sim_link.up.due(t_ns * 1e-9)
        self.expected, self.answers = self.sim_link.answers_due([s for s, _ in self.delivered]), 0
        for _, bundle in self.delivered:
            self._publish_bundle(bundle)

    def _network_run(self) -> None:
        """Publish ticks until one has an answer due (or the pace holds the next back, or the run ends)."""
        while True:
            self._network_tick(fresh=True)
            if self.expected or not self._network_step():
                return

    def _answer(self, item) -> None:
        """Lockstep: a plan or command of the controller, sent down the link at the tick's time."""
        if not self.started or self.done.done() or self.answers >= self.expected:
            return  # none is due (a repeat)
        begin = monotonic()
        self.sim_link.down.send(self.tick * self.control.period_s, item)
        self.answers += 1
        if self.answers == self.expected and self._network_step():
            self._network_run()
        self.busy_s += monotonic() - begin

    def _network_step(self) -> bool:
        """Lockstep steps 3-5: the packets due down taken, the period's command, one period; True: next tick now."""
        t = self.tick * self.control.period_s
        for item in self.sim_link.down.due(t):
            if self.plans is not None:
                self.plans.take(item, t)
            else:
                self.held = (t, item)
        if self.plans is not None:
            values = self.plans.command_at(t)
        elif self.held is not None and t - self.held[0] <= self.params["command_timeout_s"] + TIME_TOLERANCE_S:
            values = self.held[1]
        else:
            values = (0.0, 0.0, 0.0)
        return self._lockstep_period(values)

    def _on_plan(self, msg) -> None:
        if self.lockstep:
            self._answer(msg)
        else:  # realtime: taken when the link delivers it
            self.radio.send("down", lambda: self._take_plan(msg))

    def _take_plan(self, msg) -> None:
        begin = monotonic()
        self._advance(begin)  # the periods ended so far with the plans held so far, ...
        self.plans.period_command(self.clock_offset_s + self.started_at + self.hold.grid * self.hold.dt)
        # ... and the command of the period running now chosen before the plan is taken: it acts from the next
        if self.plans.take(msg, self.clock_offset_s + begin):
            self.timing.command(begin)
        self.busy_s += monotonic() - begin

    def _advance_plans(self, target: int) -> None:
        """Drive the grid up to the last control period's start at or before `target`, each period with the command
        the plans held at its start gave (`PlantPlans.period_command`; robot clock = steady + `clock_offset_s`),
        zero where no plan covers it. The measurements are thus taken, and stamped, on the control grid, where
        the controller's plans place their entries.
        """
        hold, origin = self.hold, self.clock_offset_s + self.started_at
        per_period = round(self.plans.period_s / hold.dt)  # grid steps per control period (stamps at multiples)
        target -= target % per_period  # whole periods: the odometry is measured at a period's start
        while hold.grid < target:
            start = hold.grid - hold.grid % per_period
            values = self.plans.period_command(origin + start * hold.dt)
            end = min(target, start + per_period, hold.grid + MAX_CHUNK)
            self._drive_for_peak(np.array(values), (end - hold.grid) * hold.dt)
            hold.grid = end
