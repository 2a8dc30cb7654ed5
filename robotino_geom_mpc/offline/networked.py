"""The offline loop over an emulated radio link: odometry up, command plans down, a plan buffer on the robot.

`simulation.run_scenario` runs this loop when it is given a link; all times
are sim time (the robot's clock). One `network.link.Link` per direction,
each with its own seeded generator: the up-link (odometry and the robot's
reports) seeded ``seed + 1``, the down-link (commands) ``seed + 2``. A
packet delivered at time d is handled at the first tick t_k >= d
(to `network.plan.TIME_TOLERANCE_S`): the loop, like the lockstep DDS loop,
advances in whole periods. Packets due at the same tick are handled in the
order of their delivery times, then of their sending.

Each tick k (t_k = k Ts), in this order (the lockstep DDS loop reproduces it):

1. the robot measures its odometry at t_k exactly as the undelayed loop does
   (`simulation`'s step 1) and sends one up-link packet, ``up.transmit(t_k)``:
   the odometry (stamp t_k), the report of what it applied at tick k - 1
   (period start, plan basis, entry index; or no plan) and the receipts of
   tick k - 1 (basis, receipt time t_{k-1} and whether the buffer took it,
   for every plan it was offered); nothing is sent about tick -1;
2. the controller takes the up-link packets due by t_k: for each, the
   receipts (`report_receipt`), then the applied report (`report_applied`),
   then the odometry: compensated, ``plan = controller.plan(stamp, X,
   reference rows stamp + Ts ..)`` (None for an odometry not newer than one
   taken); each plan is sent down, ``down.transmit(t_k)``;
   uncompensated, ``controller.step(X, preview, dt)`` for each odometry newer
   than the last (dt from the stamps, `step_interval`) and its voltages (or
   `next_velocity`) sent down as a one-entry command;
3. the robot takes the down-link packets due by t_k: compensated,
   ``buffer.offer(plan, t_k)`` each (`network.plan.PlanBuffer`) and notes
   their receipt for step 1 of the next tick; uncompensated, the last one to
   arrive replaces the held command;
4. the robot's command for [t_k, t_k + Ts): compensated,
   ``buffer.command_at(t_k)`` (zero without a plan); uncompensated, the held
   command, zero when it arrived more than `COMMAND_TIMEOUT_S` ago (the plant
   node's watchdog) or none has;

The robot's side of steps 1, 3 and 4 is `loop.command_link.CommandLink` (the lockstep plant node runs the
same object); the controller's side of step 2 is here.
5. record and step the plant as the undelayed loop does (its steps 4-5).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController
from robotino_geom_mpc.control.motion_controller import MotionController, odometry_state_floats
from robotino_geom_mpc.loop.command_link import COMMAND_TIMEOUT_S, CommandLink
from robotino_geom_mpc.loop.events import AppliedReport
from robotino_geom_mpc.loop.plan_follower import PlanFollower
from robotino_geom_mpc.network.link import LinkParams

__all__ = ["COMMAND_TIMEOUT_S", "NetworkedLoop", "link_meta"]


class NetworkedLoop:
    """The robot's and the controller's sides of steps 1-4 (the module docstring) for one run.

    Parameters
    ----------
    controller
        A `DelayCompensatingController` (compensated) or a `MotionController` (uncompensated baseline).
    targets
        The reference at j Ts, rows j = 0 .. (enough for the largest stamp's preview).
    period_s
        Ts [s].
    link_up, link_down
        The two directions; None is a perfect link.
    seed
        The run's seed (up-link ``seed + 1``, down-link ``seed + 2``).
    command_interface
        ``voltages`` or ``cmd_vel`` (what the uncompensated controller sends).
    """

    def __init__(self, controller: DelayCompensatingController | MotionController, targets: np.ndarray,
                 period_s: float, link_up: LinkParams | None, link_down: LinkParams | None, seed: int,
                 command_interface: str) -> None:
        self.controller = controller
        self.compensated = isinstance(controller, DelayCompensatingController)
        self.targets, self.period_s = targets, period_s
        self.follower = PlanFollower(period_s) if self.compensated else None
        self.robot = CommandLink(link_up, link_down, seed, self.follower)
        self.cmd_vel = command_interface == "cmd_vel"
        self._last_stamp: int | None = None

    def command(self, k: int, pose: tuple[float, float, float], twist: tuple[float, float, float]
                ) -> tuple[float, float, float]:
        """Steps 1-4 of tick k for the odometry (pose, twist) measured at t_k: the command for the period."""
        t = k * self.period_s
        robot = self.robot
        for stamp_k, X, reports in robot.send_up(t, (k, odometry_state_floats(pose, twist), robot.pop_reports())):
            self._controller_takes(t, stamp_k, X, reports)
        robot.take_due(t)
        return robot.period_command(t)

    def _controller_takes(self, t: float, stamp_k: int, X: tuple, reports: list[AppliedReport]) -> None:
        """Step 2 for one up-link packet."""
        Ts, controller = self.period_s, self.controller
        if isinstance(controller, DelayCompensatingController):
            for report in reports:  # the receipts, then what was applied (the robot's order)
                if report.values is not None:
                    controller.report_applied(report.time_s, report.basis_s, report.entry_index)
                elif report.basis_s is not None:  # (a receipt always names its plan)
                    controller.report_receipt(report.basis_s, report.time_s, report.taken)
            plan = controller.plan(stamp_k * Ts, X, self.targets[stamp_k + 1: stamp_k + 1 + controller.preview_length])
            if plan is not None:
                self.robot.send_down(t, plan)
            return
        if self._last_stamp is not None and stamp_k <= self._last_stamp:
            return
        dt = None if self._last_stamp is None or stamp_k - self._last_stamp == 1 else (stamp_k - self._last_stamp) * Ts
        self._last_stamp = stamp_k
        out = controller.step(X, self.targets[stamp_k + 1: stamp_k + 1 + controller.horizon], dt)
        self.robot.send_down(t, controller.next_velocity() if self.cmd_vel else out.voltages)

    def meta(self) -> dict[str, Any]:
        """The link's counts for the run's meta (`RunData.meta`)."""
        up, down = self.robot.link.up.link, self.robot.link.down.link
        out: dict[str, Any] = {
            "compensated": self.compensated,
            "up": {"sent": up.sent, "lost": up.lost, "duplicated": up.duplicated},
            "down": {"sent": down.sent, "lost": down.lost, "duplicated": down.duplicated},
        }
        if isinstance(self.controller, DelayCompensatingController) and self.follower is not None:
            stats = self.controller.statistics()
            out["controller"] = {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                 for k, v in vars(stats).items()}
            buffer = self.follower.buffer
            out["buffer"] = {"accepted": buffer.accepted, "refused": dict(buffer.refused),
                             "exhausted": buffer.exhausted}
        else:
            out["timeouts"] = self.robot.timeouts
        return out


def link_meta(link: LinkParams | None) -> dict[str, float] | None:
    """A direction's parameters for the run's meta."""
    return None if link is None else dict(vars(link))
