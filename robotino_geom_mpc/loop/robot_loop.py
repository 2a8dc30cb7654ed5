"""The robot side of the control loop as a plain object: the plant, its odometry, the drive, the link, the plans.

`RobotLoop` is what a robot does, with the time handed in (no clock is read inside): measure (`measure`: the
odometry source, ideal or encoders, plus the pose noise of the run's stream), check a command (`check_command`:
refused, zero; voltages clamped to the supply as an H-bridge does) and drive with it (`drive`: the voltages held
by the H-bridges, or a twist held by the wheel-speed PI loops). Over an emulated radio link its `link`
(`loop.command_link.CommandLink`) carries the measurements up and the controller's answers down, and gives each
period's command (the plans' entry, or the held command); without one the command goes straight to `drive`.

How time advances is a strategy chosen once:

* `LockstepTicks`: tick k at t_k = k Ts; the answer of tick k drives one period and the next tick follows
  (`offline.simulation` runs it with the controller's loop on one simulated clock; the plant node's /clock is
  that clock);
* `RealtimeGrid`: the plant on a grid of 1 / ``physics_rate_hz`` of the steady clock: each command and each
  measurement first drives the grid up to now with the command held so far (zero once it is older than the
  drive's watchdog, `loop.command_hold.CommandHold`; with plans, each control period's entry), measurements are
  taken once per grid point (`RealtimeGrid.measure`: None for a grid point already measured).

A `Measurement` carries the odometry and what the drives did since the previous one (the signed peak currents and,
with cmd_vel, the PI loops' mean voltages), as the plant node publishes them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from robotino_geom_mpc.loop.command_hold import MAX_CHUNK, CommandHold
from robotino_geom_mpc.loop.command_link import CommandLink
from robotino_geom_mpc.loop.events import Level, Log
from robotino_geom_mpc.loop.plan_follower import ZERO, PlanFollower, Unreadable
from robotino_geom_mpc.loop.source_pairing import SourcePairing
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WheelSpeedLoop
from robotino_geom_mpc.network.plan import CommandPlan

__all__ = ["Drive", "LockstepTicks", "Measurement", "OdometrySource", "PeriodAccount", "PoseNoise", "RealtimeGrid",
           "RobotLoop", "TwistDrive", "VoltageDrive"]

MAX_BEHIND_S = 1.0
"""Realtime: a stall longer than this is skipped, not integrated [s]."""

Triple = tuple[float, float, float]


class OdometrySource(Protocol):
    """What a measurement reads (`model.encoders.odometry_source`: the plant itself, or its encoders)."""

    def noisy_odometry(self, noise: Triple | None) -> tuple[Any, Any]: ...


class Drive(Protocol):
    """Drives the plant for a time under a command; (the voltages applied, their mean [V]; the currents' trace
    (m, 3) [A]: at the start and at every internal substep end).
    """

    def run(self, command: Sequence[float], duration_s: float) -> tuple[list[float], np.ndarray]: ...


class VoltageDrive:
    """The wheel voltages held over the period (the H-bridges; the command is clamped before, `RobotLoop`)."""

    def __init__(self, plant: RobotinoPlant) -> None:
        self.plant = plant

    def run(self, command: Sequence[float], duration_s: float) -> tuple[list[float], np.ndarray]:
        self.plant.step(command, duration_s)  # type: ignore[arg-type]  # three floats, checked by step
        return list(command), self.plant.substep_currents


class TwistDrive:
    """A base_link twist held by the per-wheel PI speed loops (`model.speed_loop.WheelSpeedLoop`)."""

    def __init__(self, plant: RobotinoPlant, speed_loop: WheelSpeedLoop) -> None:
        self.plant, self.speed_loop = plant, speed_loop

    def run(self, command: Sequence[float], duration_s: float) -> tuple[list[float], np.ndarray]:
        held, trace = self.speed_loop.run(self.plant, command, duration_s)
        return held.mean(axis=0).tolist(), trace


class PoseNoise:
    """The run's odometry pose noise (x, y, theta): draws of ``default_rng(seed).normal`` per measurement.

    With `ticks` the run's draws are made at once (the same values as one draw per tick: the offline loop's speed).
    """

    def __init__(self, std: tuple[float, float], seed: int, ticks: int | None = None) -> None:
        position, yaw = (float(v) for v in std)
        self.scale = (position, position, yaw)
        self.active = bool(position or yaw)
        self._rng = np.random.default_rng(seed)
        self._drawn: list[list[float]] = (self._rng.normal(0.0, self.scale, (ticks, 3)).tolist()
                                          if self.active and ticks is not None else [])
        self._next = 0

    def reseed(self, seed: int) -> None:
        """A new stream (the plant node's ``seed`` changed)."""
        self._rng, self._drawn, self._next = np.random.default_rng(seed), [], 0

    def draw(self) -> Triple | None:
        """The next draw; None without noise (nothing drawn)."""
        if not self.active:
            return None
        if self._next < len(self._drawn):
            self._next += 1
            x, y, theta = self._drawn[self._next - 1]
            return x, y, theta
        x, y, theta = self._rng.normal(0.0, self.scale).tolist()
        return x, y, theta


class RobotLoop:
    """One robot (module docstring).

    Parameters
    ----------
    plant
        The simulated robot.
    source
        What its odometry reads (the plant, or `model.encoders.EncoderOdometry`).
    drive
        `VoltageDrive` or `TwistDrive` on the plant.
    period_s
        The control period Ts [s].
    noise
        The odometry's pose noise stream.
    link
        The emulated radio link with the plan buffer or the held command (`loop.command_link.CommandLink`); None:
        the controller's commands go straight to `drive`.
    lease_s
        The lease of the controller it pairs with (`admit`): another controller's commands are refused while the
        paired one has sent within this time [s].
    """

    def __init__(self, plant: RobotinoPlant, source: OdometrySource, drive: Drive, period_s: float,
                 noise: PoseNoise, link: CommandLink | None = None, lease_s: float = 0.5) -> None:
        self.plant, self.source, self.drive_, self.period_s = plant, source, drive, period_s
        self.noise, self.link = noise, link
        self.account = PeriodAccount(voltages=isinstance(drive, TwistDrive))
        self.measured = False  # a fresh measurement was taken (the next carries what the drives did since)
        self.counts = {"clamped_commands": 0, "refused_commands": 0, "command_timeouts": 0,
                       "refused_second_source": 0}
        self.pairing = SourcePairing(round(lease_s * 1e9))

    def rebuild(self, plant: RobotinoPlant, source: OdometrySource, drive: Drive, period_s: float) -> None:
        """New robot parameters: the plant (at the old one's state), its odometry and drive replaced; the counts,
        the noise stream and what the drives did since the last measurement kept.
        """
        self.plant, self.source, self.drive_, self.period_s = plant, source, drive, period_s

    def measure(self) -> tuple[Any, Any]:
        """The odometry now: (pose, body twist), pose noise of the run's stream added."""
        return self.source.noisy_odometry(self.noise.draw())

    def drive(self, command: Sequence[float]) -> tuple[list[float], np.ndarray]:
        """One control period under `command` (voltages or twist): the voltages applied and the currents' trace."""
        return self.drive_.run(command, self.period_s)

    # the node's side: commands checked, measurements with what the drives did --------------------------------
    def admit(self, source: bytes, now_ns: int) -> bool:
        """Whether a command (a plan) of `source` at steady time `now_ns` is taken: the robot is driven by one
        controller at a time (`loop.source_pairing.SourcePairing`: the first after the start or a `release`, until
        its lease expires). A refused one is counted (``refused_second_source``) and must not be applied: the
        paired controller's command stays.
        """
        if self.pairing.admit(source, now_ns):
            return True
        self.counts["refused_second_source"] += 1
        return False

    def set_lease(self, lease_s: float) -> None:
        """A new ``pairing.lease_s`` [s] (the lease held goes on under it)."""
        self.pairing.set_lease(lease_s)

    def release(self) -> bytes | None:
        """``~/release``: the next controller to command takes the robot; the source released (None: none held)."""
        return self.pairing.release()

    def check_command(self, values: Sequence[float]) -> tuple[Triple, Log | None]:
        """The command to apply for `values` and what to log: not three finite values -> zero (refused, counted);
        voltages beyond the supply -> clamped, as an H-bridge applies them (counted).
        """
        twist = isinstance(self.drive_, TwistDrive)
        if len(values) != 3 or not math.isfinite(sum(values)):
            self.counts["refused_commands"] += 1
            what = f"cmd_vel {tuple(values)}: zero twist" if twist else \
                f"wheel_voltages with {len(values)} values (need 3 finite values): zero volts"
            return ZERO, Log(Level.WARN, f"refused {what} from now ({self.counts['refused_commands']} refused so "
                                         "far)", "refused", 1.0)
        a, b, c = values
        supply = self.plant.params.supply_voltage_v
        if twist or -supply <= min(a, b, c) and max(a, b, c) <= supply:
            return (a, b, c), None
        applied = (min(max(a, -supply), supply), min(max(b, -supply), supply), min(max(c, -supply), supply))
        self.counts["clamped_commands"] += 1
        return applied, Log(Level.WARN, f"wheel_voltages {', '.join(f'{v:g}' for v in values)} V beyond the supply "
                            f"+-{supply:g} V: applied {', '.join(f'{v:g}' for v in applied)} V "
                            f"({self.counts['clamped_commands']} commands clamped so far)", "clamped", 1.0)

    def run(self, command: Sequence[float], duration_s: float) -> None:
        """Drive `duration_s` under `command`, accounted for the next measurement."""
        applied, trace = self.drive_.run(command, duration_s)
        self.account.add(applied, trace, duration_s)

    def measurement(self, stamp_ns: int) -> Measurement:
        """A fresh measurement stamped `stamp_ns`: the odometry, and (from the second on) what the drives did since
        the previous one.
        """
        pose, twist = self.measure()
        currents, voltages = self.account.take(self.plant) if self.measured else (None, None)
        self.measured = True
        return Measurement(stamp_ns, pose, twist, currents, voltages)

    def truth(self) -> tuple[Triple, Triple]:
        """The plant's true pose in odom and body twist (noise-free)."""
        return self.plant.odometry()

    def joints(self) -> tuple[list[float], list[float], list[float]]:
        """The wheels' angles [rad], speeds [rad/s] and torques gear Km i [N m]."""
        p, plant = self.plant.params, self.plant
        return (plant.wheel_angles.tolist(), plant.wheel_speeds.tolist(),
                (p.gear_ratio * p.torque_constant_n_m_per_a * plant.currents).tolist())


@dataclass(frozen=True)
class Measurement:
    """What the robot measures at `stamp_ns`: the odometry (pose with noise, body twist) and, except for the first,
    per drive the largest |armature current| since the previous measurement signed like the current now [A] and,
    with cmd_vel, the PI loops' mean voltages over that time [V] (None: no such figure).
    """

    stamp_ns: int
    pose: Triple
    twist: Triple
    currents: Triple | None
    applied_voltages: Triple | None

    @property
    def stamp_s(self) -> float:
        """The stamp [s] (the link's clock)."""
        return self.stamp_ns * 1e-9


class PeriodAccount:
    """What the drives did between two measurements: each drive's peak |current|, the time mean of the voltages.

    Parameters
    ----------
    voltages
        Whether the mean voltages are reported (cmd_vel: the PI loops' voltages are not the commands).
    """

    def __init__(self, voltages: bool) -> None:
        self.voltages = voltages
        self._peak = np.zeros(3)
        self._volt_seconds = np.zeros(3)
        self._seconds = 0.0

    def add(self, applied: Sequence[float], trace: np.ndarray, duration_s: float) -> None:
        """A stretch of `duration_s` with the mean voltages `applied` and the currents' `trace` (m, 3)."""
        self._peak = np.maximum(self._peak, np.abs(trace).max(axis=0))
        self._volt_seconds += np.asarray(applied) * duration_s
        self._seconds += duration_s

    def take(self, plant: RobotinoPlant) -> tuple[Triple, Triple | None]:
        """(the signed peaks, the mean voltages or None) since the last call; the account starts over."""
        a, b, c = np.copysign(self._peak, plant.currents).tolist()
        mean: Triple | None = None
        if self.voltages and self._seconds > 0.0:
            x, y, z = (self._volt_seconds / self._seconds).tolist()
            mean = (x, y, z)
        self._peak, self._volt_seconds, self._seconds = np.zeros(3), np.zeros(3), 0.0
        return (a, b, c), mean


class LockstepTicks:
    """Lockstep time: tick k at t_k = k Ts; each answer drives one period (module docstring).

    Parameters
    ----------
    robot
        The robot.
    ticks
        The run's number of ticks (None: until stopped).
    """

    def __init__(self, robot: RobotLoop, ticks: int | None) -> None:
        self.robot = robot
        self.period_ns = int(round(robot.period_s * 1e9))
        self.tick = 0
        self.last_tick = None if ticks is None else max(1, ticks) - 1

    @property
    def time_ns(self) -> int:
        """t_k [ns]."""
        return self.tick * self.period_ns

    @property
    def time_s(self) -> float:
        """t_k [s] (the link's and the plans' clock)."""
        return self.tick * self.robot.period_s

    def measurement(self) -> Measurement:
        """Tick k's fresh measurement."""
        return self.robot.measurement(self.time_ns)

    def period(self, command: Sequence[float]) -> bool:
        """Drive tick k's period under `command`; True: the next tick follows, False: that was the last tick."""
        self.robot.run(command, self.robot.period_s)
        if self.last_tick is not None and self.tick >= self.last_tick:
            return False
        self.tick += 1
        return True


class RealtimeGrid:
    """Realtime time: the plant driven on a grid of the steady clock (module docstring).

    Parameters
    ----------
    robot
        The robot.
    started_at
        The grid's origin, steady time [s].
    rate_hz
        The grid's rate (``physics_rate_hz``).
    timeout_s
        The drive's watchdog (``command_timeout_s``): a plain command older than this gives zero.
    follower
        With plans: the plan buffer whose entry drives each control period (robot clock = steady + the offset).
    offset_ns
        The robot clock minus the steady clock [ns] (the plans' times).
    """

    def __init__(self, robot: RobotLoop, started_at: float, rate_hz: float, timeout_s: float,
                 follower: PlanFollower | None = None, offset_ns: int = 0) -> None:
        self.robot, self.started_at, self.timeout_s = robot, started_at, timeout_s
        self.hold = CommandHold(started_at, 1.0 / rate_hz)
        self.follower, self.offset_s = follower, offset_ns * 1e-9
        self.published_grid_s = -math.inf  # the grid point of the last measurement [s, steady]

    @property
    def offset_ns(self) -> int:
        """The robot clock minus the steady clock taken at the start [ns]."""
        return round(self.offset_s * 1e9)

    @property
    def simulated_s(self) -> float:
        """The plant time driven so far [s]."""
        return self.hold.grid * self.hold.dt

    def advance(self, now: float, ceil: bool = False) -> tuple[float, list[Log]]:
        """Drive up to the grid point before (`ceil`: after) steady time `now`: (the plant's time, steady; logs)."""
        hold, logs = self.hold, []
        position = (now - self.started_at) / hold.dt
        target = math.ceil(position) if ceil else math.floor(position)
        if target - hold.grid > MAX_BEHIND_S / hold.dt:  # the process stalled: skip rather than catch up
            logs.append(Log(Level.WARN, f"plant {(target - hold.grid) * hold.dt:.2f} s behind: skipping ahead",
                            "behind", 1.0))
            hold.grid = target
        if self.follower is not None:
            self._advance_plans(target, self.follower)
        elif hold.advance(target, self.timeout_s, self.robot.run):
            counts = self.robot.counts
            counts["command_timeouts"] += 1
            logs.append(Log(Level.WARN, f"no command for {self.timeout_s:g} s: zero volts (drive watchdog; "
                            f"{counts['command_timeouts']} so far)", "timeout", 1.0))
        return self.started_at + hold.grid * hold.dt, logs

    def hold_command(self, values: Sequence[float], now: float) -> list[Log]:
        """A command (checked) held from the grid point after steady time `now`."""
        _, logs = self.advance(now, ceil=True)  # the old command up to now; the new one from the next grid point
        self.hold.hold(tuple(values), now)
        return logs

    def take_plan(self, plan: CommandPlan | Unreadable, now: float) -> tuple[str | None, list[Log]]:
        """A plan received at steady time `now`: it acts from the next control period (`PlanFollower.take`'s
        reason, logs).
        """
        assert self.follower is not None, "take_plan needs plans"
        _, logs = self.advance(now)  # the periods ended so far with the plans held so far, ...
        # ... and the command of the period running now chosen before the plan is taken: it acts from the next
        self.follower.period_command(self.offset_s + self.started_at + self.hold.grid * self.hold.dt)
        return self.follower.take(plan, self.offset_s + now), logs

    def measure(self, now: float, offset_ns: int) -> tuple[Measurement | None, list[Log]]:
        """The measurement of the grid point before steady time `now`, stamped on the robot clock (steady +
        `offset_ns`); None when that grid point was measured already (a late timer firing again).
        """
        grid_time, logs = self.advance(now)
        if grid_time <= self.published_grid_s:
            return None, logs
        self.published_grid_s = grid_time
        return self.robot.measurement(offset_ns + round(grid_time * 1e9)), logs

    def _advance_plans(self, target: int, follower: PlanFollower) -> None:
        """Drive the grid up to the last control period's start at or before `target`, each period with the command
        the plans held at its start gave (`PlanFollower.period_command`), zero where no plan covers it. The
        measurements are thus taken, and stamped, on the control grid, where the controller's plans place their
        entries.
        """
        hold, origin = self.hold, self.offset_s + self.started_at
        per_period = round(follower.period_s / hold.dt)  # grid steps per control period (stamps at multiples)
        target -= target % per_period  # whole periods: the odometry is measured at a period's start
        while hold.grid < target:
            start = hold.grid - hold.grid % per_period
            values = follower.period_command(origin + start * hold.dt)
            end = min(target, start + per_period, hold.grid + MAX_CHUNK)
            self.robot.run(values, (end - hold.grid) * hold.dt)
            hold.grid = end
