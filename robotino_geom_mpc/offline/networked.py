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
5. record and step the plant as the undelayed loop does (its steps 4-5).
"""

from __future__ import annotations

import heapq
import math
from typing import Any

import numpy as np

from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController
from robotino_geom_mpc.control.motion_controller import MotionController, odometry_state_floats
from robotino_geom_mpc.network.link import Link, LinkParams
from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S, PlanBuffer

__all__ = ["COMMAND_TIMEOUT_S", "NetworkedLoop", "link_meta"]

COMMAND_TIMEOUT_S = 0.1
"""The plant node's watchdog (its ``command_timeout_s`` default): a command held longer gives zero."""

_ZERO = (0.0, 0.0, 0.0)


class _Queue:
    """Packets in flight, handed out in order of delivery time, then of sending."""

    def __init__(self, link: Link) -> None:
        self.link, self._heap, self._seq = link, [], 0

    def send(self, now_s: float, packet: Any) -> None:
        for delivery in self.link.transmit(now_s):
            heapq.heappush(self._heap, (delivery, self._seq, packet))
            self._seq += 1

    def due(self, now_s: float) -> list[Any]:
        out = []
        while self._heap and self._heap[0][0] <= now_s + TIME_TOLERANCE_S:
            out.append(heapq.heappop(self._heap)[2])
        return out


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
        self.up = _Queue(Link(link_up or LinkParams(), seed + 1))
        self.down = _Queue(Link(link_down or LinkParams(), seed + 2))
        self.cmd_vel = command_interface == "cmd_vel"
        self.buffer = PlanBuffer()
        self._receipts: list[tuple[float, float]] = []
        self._applied: tuple[float, float | None, int] | None = None
        self._held: tuple[float, tuple[float, float, float]] | None = None  # uncompensated: (arrival, command)
        self._last_stamp: int | None = None
        self.exhausted = 0

    def command(self, k: int, pose: list[float], twist: list[float]) -> tuple[float, float, float]:
        """Steps 1-4 of tick k for the odometry (pose, twist) measured at t_k: the command for the period."""
        t = k * self.period_s
        self.up.send(t, (k, odometry_state_floats(pose, twist), self._applied, self._receipts))
        self._receipts = []
        for stamp_k, X, applied, receipts in self.up.due(t):
            self._controller_takes(t, stamp_k, X, applied, receipts)
        if self.compensated:
            for plan in self.down.due(t):
                reason = self.buffer.offer(plan, t)  # a refusal is counted by the buffer; the plans held stay
                self._receipts.append((plan.basis_s, t, reason is None))
            applied = self.buffer.command_at(t)
            self._applied = (t, None, 0) if applied is None else (t, applied.basis_s, applied.entry_index)
            return _ZERO if applied is None else applied.values
        for command in self.down.due(t):
            self._held = (t, command)
        if self._held is None or t - self._held[0] > COMMAND_TIMEOUT_S + TIME_TOLERANCE_S:
            self.exhausted += self._held is not None
            return _ZERO
        return self._held[1]

    def _controller_takes(self, t: float, stamp_k: int, X: tuple, applied, receipts) -> None:
        """Step 2 for one up-link packet."""
        Ts, controller = self.period_s, self.controller
        if self.compensated:
            for basis, received, taken in receipts:
                controller.report_receipt(basis, received, taken)
            if applied is not None:
                controller.report_applied(*applied)
            plan = controller.plan(stamp_k * Ts, X, self.targets[stamp_k + 1: stamp_k + 1 + controller.preview_length])
            if plan is not None:
                self.down.send(t, plan)
            return
        if self._last_stamp is not None and stamp_k <= self._last_stamp:
            return
        dt = None if self._last_stamp is None or stamp_k - self._last_stamp == 1 else (stamp_k - self._last_stamp) * Ts
        self._last_stamp = stamp_k
        out = controller.step(X, self.targets[stamp_k + 1: stamp_k + 1 + controller.horizon], dt)
        self.down.send(t, controller.next_velocity() if self.cmd_vel else out.voltages)

    def meta(self) -> dict[str, Any]:
        """The link's counts for the run's meta (`RunData.meta`)."""
        up, down = self.up.link, self.down.link
        out: dict[str, Any] = {
            "compensated": self.compensated,
            "up": {"sent": up.sent, "lost": up.lost, "duplicated": up.duplicated},
            "down": {"sent": down.sent, "lost": down.lost, "duplicated": down.duplicated},
        }
        if self.compensated:
            stats = self.controller.statistics()
            out["controller"] = {k: (None if isinstance(v, float) and math.isnan(v) else v)
                                 for k, v in vars(stats).items()}
            out["buffer"] = {"accepted": self.buffer.accepted, "refused": dict(self.buffer.refused),
                             "exhausted": self.buffer.exhausted}
        else:
            out["timeouts"] = self.exhausted
        return out


def link_meta(link: LinkParams | None) -> dict[str, float] | None:
    """A direction's parameters for the run's meta."""
    return None if link is None else dict(vars(link))

