"""A simulated Robotino behind its real chain: driver loop, link, firmware tick and ramps, wheel PI loops (no rclpy).

`ChainEmulator` runs a `model.plant.RobotinoPlant` through the chain of `model.driver_chain`, one event at a
time, on one clock (the host's; the firmware's tick grid starts at 0):

* firmware tick j at t = j tick_s: the newest command that has arrived (by its forwarding order; an older
  one arriving late is ignored) goes to `driver_chain.Firmware`, whose ramped setpoint the wheel PI loops
  (`model.speed_loop.WheelSpeedLoop`, gains `tuned_gains` for ``speed_loop_time_constant_s``) hold until the
  next tick; on every tick that starts an odometry period (1 / odometry_rate_hz), the odometry (pose plus
  the run's noise, body twist) is sampled and sent to the driver over the up link;
* driver pass k at t = driver_phase_s + k / driver_rate_hz (after a firmware tick at the same time): the
  odometry that arrived since the last pass is dispatched (all of it in arrival order, or the newest),
  each message stamped t; each cmd_vel received before t is forwarded once, through `driver_chain.speed_floor`,
  over the down link.

The emulation keeps what the wire does not carry: each message's true measurement time (`OdometryMessage.measured_s`),
each command's forwarding and application (`forwarded`, `applied`), per tick the setpoint, voltages and
currents (`trace`): the truth the chain's tests and the controller's time reconstruction are checked against.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from robotino_geom_mpc.arrays import float_triple
from robotino_geom_mpc.model.driver_chain import ChainError, ChainParams, Firmware, speed_floor
from robotino_geom_mpc.model.encoders import EncoderOdometry
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import DEFAULT_RATE_HZ, WheelSpeedLoop, tuned_gains
from robotino_geom_mpc.network.link import Link, LinkParams

__all__ = ["ChainEmulator", "EmulatedRobot", "OdometryMessage", "TickRecord"]


class OdometryMessage(NamedTuple):
    """One odometry message as the driver dispatches it, with the truth behind it.

    stamp_s is the driver's dispatch time (all a subscriber sees), measured_s the firmware tick it was
    sampled at (not on the wire), pose (x, y, theta) in odom and twist (v_x, v_y, theta') in base_link.
    """

    stamp_s: float
    measured_s: float
    pose: tuple[float, float, float]
    twist: tuple[float, float, float]


class TickRecord(NamedTuple):
    """One firmware tick: its time, the true pose at it, the setpoint held after it, the mean PI voltages
    over the tick and the largest |current| per motor over it (signed like the current at its end).
    """

    time_s: float
    pose: tuple[float, float, float]
    setpoint: tuple[float, float, float]
    voltages: tuple[float, float, float]
    currents: tuple[float, float, float]


class ChainEmulator:
    """The plant behind the driver, link and firmware (module docstring).

    Parameters
    ----------
    plant
        The simulated robot (its time is the emulation's: it must start at 0).
    params
        The chain.
    seed
        Seeds the two links (down: seed, up: seed + 1) and the odometry noise (seed + 2).
    odometry_noise
        (position [m], yaw [rad]) standard deviations of the firmware odometry's pose noise (two numbers).
    source
        What an odometry sample reads (`model.encoders.odometry_source`); the plant itself if None.
    speed_loop_rate_hz
        Sampling rate of the wheels' PI loops (`model.speed_loop.DEFAULT_RATE_HZ`, 1 kHz, by default).
    """

    def __init__(self, plant: RobotinoPlant, params: ChainParams, seed: int = 0,
                 odometry_noise: Sequence[float] = (0.0, 0.0),
                 source: RobotinoPlant | EncoderOdometry | None = None,
                 speed_loop_rate_hz: float = DEFAULT_RATE_HZ) -> None:
        self.plant, self.params = plant, params
        self.firmware = Firmware(params)
        self.speed_loop = WheelSpeedLoop(plant.params, *tuned_gains(plant.params, params.speed_loop_time_constant_s),
                                         speed_loop_rate_hz)
        link = LinkParams(params.link_delay_s, params.link_jitter_s, params.link_loss)
        self.down, self.up = Link(link, seed), Link(link, seed + 1)
        self._rng = np.random.default_rng(seed + 2)
        self._noise = tuple(float(v) for v in odometry_noise)
        self._source = plant if source is None else source
        self._ticks_per_odometry = round(params.odometry_period_s / params.tick_s)
        self._tick = 0
        self._pass = 0
        self._sample = 0
        self._odometry: list[tuple[float, int, OdometryMessage]] = []  # (arrival, sample number, message)
        self._last_dispatched = -1
        self._received: list[tuple[float, tuple[float, float, float]]] = []  # cmd_vels at the driver
        self._in_flight: list[tuple[float, int, tuple[float, float, float]]] = []  # (arrival, seq, twist)
        self._applied_seq = -1
        self._now = 0.0
        self.forwarded: list[tuple[float, int, tuple[float, float, float]]] = []  # (time, seq, twist sent)
        self.applied: list[tuple[float, int]] = []  # (tick time, seq) of each command the firmware took
        self.trace: list[TickRecord] = []

    @property
    def time_s(self) -> float:
        """The time up to which events have run [s]."""
        return self._now

    def next_tick_s(self) -> float:
        """The time of the next firmware tick [s]."""
        return self._tick * self.params.tick_s

    def next_pass_s(self) -> float:
        """The time of the driver's next loop pass [s]."""
        return self.params.driver_phase_s + self._pass * self.params.driver_period_s

    def cmd_vel(self, twist: tuple[float, float, float], time_s: float) -> None:
        """A cmd_vel (v_x, v_y, theta') reaches the driver at `time_s`: forwarded at its next pass after it."""
        if len(twist) != 3 or not all(math.isfinite(float(v)) for v in twist):
            raise ChainError(f"cmd_vel must be three finite numbers, got {twist!r}")
        if time_s < self._now - 1e-12:
            raise ChainError(f"cmd_vel at {time_s!r} s is before the emulation's time {self._now!r} s")
        self._received.append((float(time_s), float_triple(twist)))

    def run_until(self, end_s: float) -> list[OdometryMessage]:
        """Run every event up to `end_s` (inclusive; a tick before a pass at the same time).

        Returns the odometry the driver dispatched meanwhile, in dispatch order.
        """
        out: list[OdometryMessage] = []
        while True:
            tick, loop = self.next_tick_s(), self.next_pass_s()
            if min(tick, loop) > end_s + 1e-12:
                break
            if tick <= loop + 1e-12:
                self._run_tick(tick)
            else:
                out += self._run_pass(loop)
        self._now = max(self._now, end_s)
        return out

    def _run_tick(self, t: float) -> None:
        arrived = [item for item in self._in_flight if item[0] <= t + 1e-12]
        if arrived:
            self._in_flight = [item for item in self._in_flight if item[0] > t + 1e-12]
            arrival, seq, twist = max(arrived, key=lambda item: item[1])
            if seq > self._applied_seq:
                self._applied_seq = seq
                self.firmware.receive(twist, arrival)
                self.applied.append((t, seq))
        setpoint = self.firmware.tick(t)
        if self._tick % self._ticks_per_odometry == 0:
            draw = self._rng.normal(0.0, (self._noise[0], self._noise[0], self._noise[1])).tolist() \
                if any(self._noise) else None
            pose, twist = self._source.noisy_odometry(draw)
            message = OdometryMessage(math.nan, t, pose, twist)
            for arrival in self.up.transmit(t):
                self._odometry.append((arrival, self._sample, message))
            self._sample += 1
        pose = float_triple(self.plant.pose)
        voltages, currents = self.speed_loop.run(self.plant, setpoint, self.params.tick_s)
        peak = np.copysign(np.abs(currents).max(axis=0), currents[-1])
        self.trace.append(TickRecord(t, pose, setpoint, tuple(voltages.mean(axis=0).tolist()), tuple(peak.tolist())))
        self._tick += 1
        self._now = t

    def _run_pass(self, t: float) -> list[OdometryMessage]:
        ready = sorted((item for item in self._odometry if item[0] <= t + 1e-12), key=lambda item: item[0])
        self._odometry = [item for item in self._odometry if item[0] > t + 1e-12]
        if self.params.odometry_dispatch == "latest" and ready:
            newest = max(ready, key=lambda item: item[1])
            ready = [newest] if newest[1] > self._last_dispatched else []
        out = []
        for _, sample, message in ready:
            self._last_dispatched = max(self._last_dispatched, sample)
            out.append(message._replace(stamp_s=t))
        waiting = [item for item in self._received if item[0] < t - 1e-12]
        self._received = [item for item in self._received if item[0] >= t - 1e-12]
        for _, twist in waiting:
            seq = len(self.forwarded)
            sent = speed_floor(twist, self.params)
            self.forwarded.append((t, seq, sent))
            for arrival in self.down.transmit(t):
                self._in_flight.append((arrival, seq, sent))
        self._pass += 1
        self._now = t
        return out


class EmulatedRobot:
    """The emulated chain as a `control.chain_identification.RobotIO`: `poll` to the next dispatch, `send` a cmd_vel."""

    def __init__(self, emulator: ChainEmulator) -> None:
        self.emulator = emulator
        self.now_s = 0.0

    def poll(self) -> tuple[float, list[tuple[float, tuple, tuple]]]:
        """Run to the driver's next pass that dispatches odometry; (its time, the messages)."""
        while True:
            self.now_s = self.emulator.next_pass_s()
            messages = self.emulator.run_until(self.now_s)
            if messages:
                return self.now_s, [(m.stamp_s, m.pose, m.twist) for m in messages]

    def send(self, twist: tuple[float, float, float]) -> None:
        """A cmd_vel reaching the driver now."""
        self.emulator.cmd_vel(twist, self.now_s)
