"""The realtime plant's command, held on its integration grid, with the drive's watchdog.

A command applies from the grid point after its arrival until the next
command. From the first grid point at which it is older than the timeout the
drives get zero volts, as a real drive's watchdog gives them; each command
that times out is reported once. The grid steps are driven in runs of
constant voltage of at most `MAX_CHUNK` steps, so the plant steps with few
step sizes (their matrices stay cached).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from robotino_geom_mpc.model.plant import RobotinoPlant

__all__ = ["MAX_CHUNK", "ZERO_VOLTS", "CommandHold", "warm_up"]

MAX_CHUNK = 10  # grid steps per plant step
ZERO_VOLTS = (0.0, 0.0, 0.0)


class CommandHold:
    """The held command on a grid of `dt` [s] from steady time `started_at` [s]; `grid` points are driven so far."""

    def __init__(self, started_at: float, dt: float) -> None:
        self.started_at, self.dt = started_at, dt
        self.grid = 0
        self.voltages: tuple[float, float, float] = ZERO_VOLTS
        self.command_time = -math.inf  # steady time of the last command
        self._timed_out = -math.inf  # the command_time of the last command the watchdog stopped

    def hold(self, voltages: tuple[float, ...], now: float) -> None:
        """Hold `voltages` from steady time `now` (after driving the grid up to it)."""
        a, b, c = voltages
        self.voltages, self.command_time = (float(a), float(b), float(c)), now

    def advance(self, target: int, timeout_s: float, drive: Callable[[Sequence[float], float], None]) -> bool:
        """Drive the grid up to point `target` (`drive(voltages, seconds)` per run); True if the held command
        timed out in it (once per command).
        """
        held = math.isfinite(self.command_time)
        stale = math.floor((self.command_time + timeout_s - self.started_at) / self.dt) + 1 if held else self.grid
        while self.grid < target:
            fresh = self.grid < stale
            end = min(min(target, stale) if fresh else target, self.grid + MAX_CHUNK)
            drive(self.voltages if fresh else ZERO_VOLTS, (end - self.grid) * self.dt)
            self.grid = end
        if held and self.grid > stale and self._timed_out != self.command_time:
            self._timed_out = self.command_time
            return True
        return False


def warm_up(plant: RobotinoPlant, dt: float) -> None:
    """Compute now the plant's matrices of every step size a hold on a grid of `dt` uses (1 .. `MAX_CHUNK` steps:
    an uncached step size costs milliseconds of expm), and return it to its state.
    """
    state = plant.state
    for k in range(1, MAX_CHUNK + 1):
        plant.step(np.zeros(3), k * dt)
    plant.reset(state)
