"""The robot side of the control loop as a plain object: the plant, its odometry, the drive, the link, the plans.

`RobotLoop` is what a robot does each control period, with the time handed in (robot clock, seconds; no clock is
read inside): measure (`measure`: the odometry source, ideal or encoders, plus the pose noise of the run's
stream) and drive one period with a command (`drive`: the voltages held by the H-bridges, or a twist held by the
wheel-speed PI loops). Over an emulated radio link its `link` (`loop.command_link.CommandLink`) carries the
measurements up and the controller's answers down, and gives each period's command (the plans' entry, or the
held command); without one the controller's command goes straight to `drive`.

Who drives it: `offline.simulation` (one simulated clock, with `loop.controller_loop` on the other side) and the
plant node in lockstep (its /clock is the same clock). The order of one networked tick is the one
`offline.networked` writes down.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from robotino_geom_mpc.loop.command_link import CommandLink
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WheelSpeedLoop

__all__ = ["Drive", "OdometrySource", "PoseNoise", "RobotLoop", "TwistDrive", "VoltageDrive"]

Triple = tuple[float, float, float]


class OdometrySource(Protocol):
    """What a measurement reads (`model.encoders.odometry_source`: the plant itself, or its encoders)."""

    def noisy_odometry_floats(self, noise: Triple | None) -> tuple[Any, Any]: ...


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
    """

    def __init__(self, plant: RobotinoPlant, source: OdometrySource, drive: Drive, period_s: float,
                 noise: PoseNoise, link: CommandLink | None = None) -> None:
        self.plant, self.source, self.drive_, self.period_s = plant, source, drive, period_s
        self.noise, self.link = noise, link

    def measure(self) -> tuple[Any, Any]:
        """The odometry now: (pose, body twist), pose noise of the run's stream added."""
        return self.source.noisy_odometry_floats(self.noise.draw())

    def drive(self, command: Sequence[float]) -> tuple[list[float], np.ndarray]:
        """One control period under `command` (voltages or twist): the voltages applied and the currents' trace."""
        return self.drive_.run(command, self.period_s)
