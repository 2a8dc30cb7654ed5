"""The robot behind the real driver's chain, run on a clock handed in: `model.chain_emulation.ChainEmulator` polled.

What the plant node does with ``chain.active`` enabled (realtime, cmd_vel), as a plain object: the emulation's
time t is the steady time since the first poll (not the node's construction: the passes due while it started
would come out in one burst); a stamp is the node clock at that first poll plus t. Each poll runs the emulation's
events up to now, one driver pass at a time: the odometry the driver dispatched at the pass (stamped with the
pass's time) and the plant's state after it (`ChainState`: the ground truth's stamp, the signed peak currents
over the firmware ticks run since the last pass and their PI voltages' mean). A pass run more than `LATE_S` after
its time is counted (the host could not keep up).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from robotino_geom_mpc.loop.events import Level, Log
from robotino_geom_mpc.loop.robot_loop import Measurement, PeriodAccount
from robotino_geom_mpc.model.chain_emulation import ChainEmulator

__all__ = ["ChainPass", "ChainRobot", "ChainState", "LATE_S"]

LATE_S = 0.05
"""A driver pass run later than this after its time is late [s]."""

Triple = tuple[float, float, float]


@dataclass(frozen=True)
class ChainState:
    """The plant after a pass: the stamp of its time [ns], the signed peak currents and the mean PI voltages over the
    firmware ticks since the last pass.
    """

    stamp_ns: int
    currents: Triple
    applied_voltages: Triple | None


@dataclass(frozen=True)
class ChainPass:
    """One driver pass: the odometry it dispatched, the plant's state after it (None: no tick ran), how late [s], and
    the emulation's true measurement time of each odometry [s] (the offline run's timing figures).
    """

    odometry: list[Measurement]
    state: ChainState | None
    late_s: float
    measured_s: list[float]


class ChainRobot:
    """The emulated chain on a clock handed in (module docstring).

    Parameters
    ----------
    emulator
        The chain in front of the plant (its plant starts at time 0).
    """

    def __init__(self, emulator: ChainEmulator) -> None:
        self.emulator = emulator
        self.account = PeriodAccount(voltages=True)
        self.started_at: float | None = None  # steady time of the first poll
        self.start_ns = 0  # the node clock then
        self.published_ticks = 0
        self.dispatched = 0
        self.commands = 0

    def _stamp_ns(self, t: float) -> int:
        return self.start_ns + int(round(t * 1e9))

    def command(self, values: Sequence[float], now: float) -> Log | None:
        """A cmd_vel's values at steady time `now`: forwarded to the driver (`cmd_vel`) when three finite values,
        else refused (not forwarded) with the line to log.
        """
        if len(values) != 3 or not math.isfinite(sum(values)):
            return Log(Level.WARN, f"refused cmd_vel {tuple(values)}: not forwarded", "refused", 1.0)
        a, b, c = values
        self.cmd_vel((a, b, c), now)
        return None

    def cmd_vel(self, twist: Triple, now: float) -> bool:
        """A cmd_vel at steady time `now` reaches the driver; False before the chain's first instant (dropped)."""
        if self.started_at is None:
            return False
        self.commands += 1
        self.emulator.cmd_vel(twist, max(now - self.started_at, self.emulator.time_s))
        return True

    def elapsed_s(self, now: float, clock_ns: int) -> float:
        """The emulation's time at steady time `now` (the first call starts it, with the node clock `clock_ns`)."""
        if self.started_at is None:
            self.started_at, self.start_ns = now, clock_ns
        return now - self.started_at

    def poll(self, now: float, clock_ns: int) -> list[ChainPass]:
        """Run the driver passes due by steady time `now` (node clock `clock_ns`): one `ChainPass` each."""
        emulator, out = self.emulator, []
        elapsed = self.elapsed_s(now, clock_ns)
        while emulator.next_pass_s() <= elapsed:
            t_pass = emulator.next_pass_s()
            messages = emulator.run_until(t_pass)
            odometry = [Measurement(self._stamp_ns(m.stamp_s), m.pose, m.twist, None, None) for m in messages]
            self.dispatched += len(odometry)
            out.append(ChainPass(odometry, self._state(), elapsed - t_pass, [m.measured_s for m in messages]))
        return out

    def _state(self) -> ChainState | None:
        """The plant's state after the ticks run since the last pass (None: none ran)."""
        emulator = self.emulator
        ticks = emulator.trace[self.published_ticks:]
        if not ticks:
            return None
        self.published_ticks = len(emulator.trace)
        tick_s = emulator.params.tick_s
        for record in ticks:
            self.account.add(record.voltages, np.array([record.currents]), tick_s)
        currents, voltages = self.account.take(emulator.plant)
        return ChainState(self._stamp_ns(emulator.plant.time_s), currents, voltages)
