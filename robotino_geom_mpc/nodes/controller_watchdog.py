"""The controller node's watchdog: stale odometry or reference gives zero volts and a bumpless restart later.

`ControllerWatchdog` is a part of `controller_node.ControllerNode` (a mixin over the node's state); its
steady-clock timer runs at half the shorter timeout and says, throttled, what the node waits for.
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.clock import Clock, ClockType

from robotino_geom_mpc.ros.throttle import info_throttled, warn_throttled

__all__ = ["ControllerWatchdog"]

_WAIT_LOG_PERIOD_S = 5.0  # throttle of the "waiting for ..." log


class ControllerWatchdog:
    """The watchdog methods of the controller node."""

    def _start_watchdog(self):
        """The timer of the watchdog, at half the shorter timeout, on the watchdog's clock (`_watch_now`)."""
        timeout = min(self.params["odom_timeout_s"], self.params["reference_timeout_s"])
        clock = self.get_clock() if self.sim_time else Clock(clock_type=ClockType.STEADY_TIME)
        return self.create_timer(timeout / 2, self._check_watchdog, clock=clock)

    def _log_wait(self, now: float) -> None:
        """Say what the controller waits for when it has heard nothing for a timeout (throttled)."""
        if self.pending is not None and now - self.pending_since > self.params["reference_timeout_s"]:
            what = (f"the odometry of stamp {self.pending[0]} ns waits {now - self.pending_since:.1f} s for the "
                    f"reference_preview of that stamp on {self.preview_sub.topic_name} "
                    f"({self.count_publishers(self.preview_sub.topic_name)} publishers)")
        elif now - (self.odom_time or self.start_time) > self.params["odom_timeout_s"]:
            heard = "since the start" if self.odom_time is None else "since the last one"
            what = (f"no odometry on {self.odom_sub.topic_name} for {now - (self.odom_time or self.start_time):.1f} s "
                    f"{heard} ({self.count_publishers(self.odom_sub.topic_name)} publishers)")
        elif self.preview_time is None and now - self.start_time > self.params["reference_timeout_s"]:
            what = (f"no reference_preview on {self.preview_sub.topic_name} yet "
                    f"({self.count_publishers(self.preview_sub.topic_name)} publishers)")
        else:
            return
        info_throttled(self.get_logger(), f"waiting: {what}", _WAIT_LOG_PERIOD_S)

    def _check_watchdog(self) -> None:
        now = self._watch_now()  # the node clock under use_sim_time, else steady time
        if self.odom_time is None or self.preview_time is None or self.lockstep:
            self._log_wait(now)  # lockstep: the plant holds the time; only say what is missing
            if self.odom_time is None or self.preview_time is None:
                return
        if now - self.odom_time > self.params["odom_timeout_s"]:
            state = "stale_odom"
        elif now - self.preview_time > self.params["reference_timeout_s"]:
            state = "stale_reference"
        else:
            state = "ok"
        self.watchdog_state = state
        if state == "ok" or self.lockstep:
            return
        self.blend.request("watchdog")  # data that return restart the tracking bumplessly
        # and are taken on any fresh stamp, also one before the last used (a sim clock reset, a bag replayed in a loop)
        self.last_odom_ns, self.latest_preview = None, None
        warn_throttled(self.get_logger(), f"watchdog: {state.replace('_', ' ')}; zero volts", 1.0)
        self.outputs.send_zero()
        self.outputs.diagnose(None, DiagnosticStatus.WARN, f"watchdog: {state}")
