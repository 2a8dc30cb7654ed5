"""The lockstep plant's run: the start handshake, the resends, a period per answer, the pace, the run's report.

`PlantLockstep` is a part of `plant_node.PlantNode` (a mixin over the node's plant, publishers and counters;
the module docstring of `plant_node` gives the behaviour).
"""

from __future__ import annotations

from robotino_geom_mpc.ros.qos import publish_acknowledged, wait_acknowledged
from robotino_geom_mpc.ros.spin import FINISHED_ACK_WAIT_S, data_publishers, monotonic
from robotino_sim_node.loop_timing import lockstep_line, lockstep_report, write_report
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["PlantLockstep"]


class PlantLockstep:
    """The lockstep methods of the plant node."""

    def _try_start(self) -> None:
        now = monotonic()
        if self.handshake.poll(now, self.params["lockstep_settle_s"]):
            self.start_timer.cancel()
            self.started = True
            self.started_at = now
            self._publish_tick(fresh=True)

    def _resend(self) -> None:
        now = monotonic()
        if self.started and not self.done.done() and self.pace_timer.is_canceled() \
                and now - self.published_at > self.params["lockstep_resend_s"]:
            self.resent += 1
            warn_throttled(self.get_logger(), f"no command for tick {self.tick} (t = {self._time_ns() * 1e-9:.3f} s) "
                           f"for {now - self.tick_sent_at:.1f} s: resending ({self.resent} resends so far)", 2.0)
            self._publish_tick(fresh=False)

    def _lockstep_period(self, values: tuple[float, ...]) -> bool:
        """Integrate the tick's period under `values` and go to the next tick; True: publish it now (else the
        pace holds it back, or the run is over).
        """
        begin = monotonic()
        self.wait_s += begin - self.published_at
        self.peak_currents = self._drive(values, self.control.period_s)
        self.have_period = True
        if self.tick == 0:
            self.first_answer_at = begin
            self.busy_s = self.wait_s = 0.0  # per-tick figures of the running loop (ticks 1 ..)
        if self.last_tick is not None and self.tick >= self.last_tick:
            self._publish_currents()  # of the last period; no tick follows
            for msg in self.plans.pop_reports() if self.plans is not None else ():  # and what it applied
                publish_acknowledged(self, self.applied_pub, msg)
            self._report_run(begin)
            self.done.set_result(True)  # the last tick is answered: the run is over
            return False
        self.tick += 1
        delay = self.pace.delay(monotonic())
        if delay > 0.0:
            self.pace_timer.timer_period_ns = max(1, int(delay * 1e9))
            self.pace_timer.reset()
            return False
        return True

    def _paced_tick(self) -> None:  # the tick `lockstep_max_realtime_factor` held back, at its slot
        self.pace_timer.cancel()
        self._publish_tick(fresh=True)

    def _report_run(self, last_answer_at: float) -> None:
        """Log the run's real-time factor (ticks 1 .. n - 1, from the answer of tick 0 to that of the last)."""
        report = lockstep_report(self.tick + 1, self.control.period_s, self.started_at, self.first_answer_at,
                                 last_answer_at, self.busy_s, self.wait_s, resent=self.resent, **self.counts)
        self.get_logger().info(lockstep_line(report))
        self._write_report(report)

    def _write_report(self, report: dict) -> None:
        """Write the timing report to ``timing_report`` (if set) when the readers have the run's samples (so `run`
        may stop the other nodes once it is there); a failure is logged and the exit status 1.
        """
        if self.params["timing_report"]:
            wait_acknowledged(self, data_publishers(self), FINISHED_ACK_WAIT_S)
            try:
                write_report(self.params["timing_report"], report)
            except OSError as exc:
                self.get_logger().error(f"cannot write the timing report: {exc}")
                self.exit_status = 1
