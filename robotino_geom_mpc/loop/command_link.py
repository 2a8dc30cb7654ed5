"""The robot's end of the emulated radio link in lockstep: packets up, the controller's answers down, the command.

Each tick k at t_k = k Ts (robot clock, seconds, handed in), in the order `offline.networked` writes down (the
lockstep plant node follows it too):

1. `send_up(t_k, packet)`: the robot's packet of the tick (its odometry, with the reports of the plans since the
   last packet, `pop_reports`) goes up; the packets the controller gets now come back, in order;
2. the controller's answers (plans, or plain commands) go down, `send_down(t_k, answer)`;
3. `take_due(t_k)`: the answers the down link delivers by t_k are taken: plans offered to the buffer
   (`loop.plan_follower.PlanFollower`, receipt reported), or the last plain command held;
4. `period_command(t_k)`: the command of [t_k, t_k + Ts): the plans' entry (reported; zero when every plan is
   used up), or the held command (zero once it is older than the drive's watchdog, `command_timeout_s`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from robotino_geom_mpc.loop.link_queue import RobotLink
from robotino_geom_mpc.loop.events import AppliedReport
from robotino_geom_mpc.loop.plan_follower import ZERO, PlanFollower
from robotino_geom_mpc.network.link import LinkParams
from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S, CommandPlan

__all__ = ["COMMAND_TIMEOUT_S", "CommandLink"]

COMMAND_TIMEOUT_S = 0.1
"""The drive's watchdog (the plant node's ``command_timeout_s`` default): a command held longer gives zero."""

Triple = tuple[float, float, float]


class CommandLink:
    """The robot's end of the link (module docstring).

    Parameters
    ----------
    up, down
        The directions (None: perfect).
    seed
        The run's seed (up ``seed + 1``, down ``seed + 2``).
    follower
        The plan buffer (the controller sends plans); None: plain commands, held.
    command_timeout_s
        A plain command held longer than this gives zero [s].
    """

    def __init__(self, up: LinkParams | None, down: LinkParams | None, seed: int,
                 follower: PlanFollower | None = None, command_timeout_s: float = COMMAND_TIMEOUT_S) -> None:
        self.link = RobotLink(up, down, seed)
        self.follower = follower
        self.command_timeout_s = command_timeout_s
        self.held: tuple[float, Triple] | None = None  # a plain command: (arrival, values)
        self.timeouts = 0  # periods the watchdog gave zero for a command held too long

    def send_up(self, now_s: float, packet: Any) -> list[Any]:
        """Step 1: the robot's packet of this tick up the link; the packets the controller gets now, in order."""
        self.link.up.send(now_s, packet)
        return self.link.up.due(now_s)

    def send_down(self, now_s: float, answer: CommandPlan | Sequence[float]) -> None:
        """Step 2: the controller's answer (a plan, or a plain command) down the link at `now_s`."""
        self.link.down.send(now_s, answer)

    def take_due(self, now_s: float) -> list[tuple[Any, str | None]]:
        """Step 3: what the down link delivers by `now_s`: plans offered to the buffer, or the last plain command;
        each with the buffer's refusal (None: taken).
        """
        out: list[tuple[Any, str | None]] = []
        for item in self.link.down.due(now_s):
            if self.follower is not None:
                out.append((item, self.follower.take(item, now_s)))
            else:
                self.held = (now_s, item)
                out.append((item, None))
        return out

    def period_command(self, now_s: float) -> Triple:
        """Step 4: the command of the period starting at `now_s`."""
        if self.follower is not None:
            return self.follower.command_at(now_s)[1]
        if self.held is None or now_s - self.held[0] > self.command_timeout_s + TIME_TOLERANCE_S:
            self.timeouts += self.held is not None
            return ZERO
        return self.held[1]

    def pop_reports(self) -> list[AppliedReport]:
        """The plan reports since the last packet (none without plans), oldest first."""
        return [] if self.follower is None else self.follower.pop_reports()
