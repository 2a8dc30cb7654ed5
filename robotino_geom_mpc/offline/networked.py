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
2. the controller (a `loop.controller_loop.ControllerLoop` in lockstep, the
   controller node's protocol) takes the tick's preview
   (`offline.lockstep.PreviewRows`), then the up-link packets due by t_k:
   for each, the reports (`on_report`: receipts, then the applied report, in
   the robot's order), then the odometry (`on_odometry`; one not newer than
   one taken is dropped as old): compensated, its plan (`PlanOut`) is sent
   down, ``down.transmit(t_k)``; uncompensated, the MPC step's voltages (or
   twist) (`Command`; dt from the integer-ns stamps, `step_interval`) as a
   one-entry command;
3. the robot takes the down-link packets due by t_k: compensated,
   ``buffer.offer(plan, t_k)`` each (`network.plan.PlanBuffer`) and notes
   their receipt for step 1 of the next tick; uncompensated, the last one to
   arrive replaces the held command;
4. the robot's command for [t_k, t_k + Ts): compensated,
   ``buffer.command_at(t_k)`` (zero without a plan); uncompensated, the held
   command, zero when it arrived more than `COMMAND_TIMEOUT_S` ago (the plant
   node's watchdog) or none has;
5. record and step the plant as the undelayed loop does (its steps 4-5).

The robot's side of steps 1, 3 and 4 is `loop.command_link.CommandLink` (the lockstep plant node runs the
same object, `robotino_sim_node.plant_lockstep`).
"""

from __future__ import annotations

import math
from typing import Any

from robotino_geom_mpc.loop.command_link import COMMAND_TIMEOUT_S, CommandLink
from robotino_geom_mpc.loop.controller_loop import ControllerLoop
from robotino_geom_mpc.loop.events import Command, Now, PlanarOdometry, PlanOut
from robotino_geom_mpc.network.link import LinkParams
from robotino_geom_mpc.offline.lockstep import PreviewRows

__all__ = ["COMMAND_TIMEOUT_S", "NetworkedLoop", "link_meta"]


class NetworkedLoop:
    """The robot's and the controller's sides of steps 1-4 (the module docstring) for one run.

    Parameters
    ----------
    controller
        The controller's loop in lockstep (``plans``: compensated; else the uncompensated baseline).
    previews
        The run's previews.
    robot
        The robot's end of the link (a `loop.plan_follower.PlanFollower` with plans).
    """

    def __init__(self, controller: ControllerLoop, previews: PreviewRows, robot: CommandLink) -> None:
        self.controller, self.previews, self.robot = controller, previews, robot
        self.compensated = controller.plans is not None
        self.period_s = controller.control.period_s

    def command(self, k: int, pose: tuple[float, float, float], twist: tuple[float, float, float]
                ) -> tuple[float, float, float]:
        """Steps 1-4 of tick k for the odometry (pose, twist) measured at t_k: the command for the period."""
        robot, controller = self.robot, self.controller
        t, t_ns = k * self.period_s, k * self.previews.period_ns
        now = Now(t_ns, t_ns)
        controller.on_preview(self.previews.planar(k), now)
        for odometry, reports in robot.send_up(t, (PlanarOdometry(t_ns, pose, twist), robot.pop_reports())):
            for report in reports:  # the receipts, then what was applied (the robot's order)
                controller.on_report(report, now)
            for out in controller.on_odometry(odometry, now):
                if isinstance(out, PlanOut) or (isinstance(out, Command) and not self.compensated):
                    robot.send_down(t, out.plan if isinstance(out, PlanOut) else out.values)
        robot.take_due(t)
        return robot.period_command(t)

    def meta(self) -> dict[str, Any]:
        """The link's counts for the run's meta (`RunData.meta`)."""
        up, down = self.robot.link.up.link, self.robot.link.down.link
        out: dict[str, Any] = {
            "compensated": self.compensated,
            "up": {"sent": up.sent, "lost": up.lost, "duplicated": up.duplicated},
            "down": {"sent": down.sent, "lost": down.lost, "duplicated": down.duplicated},
        }
        plans, follower = self.controller.plans, self.robot.follower
        if plans is not None and follower is not None:
            out["controller"] = {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                 for k, v in vars(plans.statistics()).items()}
            buffer = follower.buffer
            out["buffer"] = {"accepted": buffer.accepted, "refused": dict(buffer.refused),
                             "exhausted": buffer.exhausted}
        else:
            out["timeouts"] = self.robot.timeouts
        return out


def link_meta(link: LinkParams | None) -> dict[str, float] | None:
    """A direction's parameters for the run's meta."""
    return None if link is None else dict(vars(link))
