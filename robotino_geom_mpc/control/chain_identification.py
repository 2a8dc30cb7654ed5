"""Identify the driver chain from a short excitation through cmd_vel: dead time, ramps, speed-loop time constant.

`run_excitation` drives a robot (anything with `RobotIO`'s two methods: the emulated chain here, the driver's
topics in `ros.identify_io`) through `Excitation`: per axis a step to a moderate speed (0.25 m/s, 1 rad/s),
commanded with a bounded acceleration (1 m/s^2, 6 rad/s^2) that the firmware's ramps, if slower, limit;
a small probe step (within one tick's ramp, so the speed loop alone shapes the response); back to rest.
About 6.6 s, every command sent once per odometry dispatch, zero at the end. After each plateau it checks
that the robot moved as commanded; if not it stops the robot (zero twist) and raises `IdentifyError`
saying why: no motion, saturation (the plateau stays below the command), or motion other than commanded.

`fit_chain` then fits the chain model the controller uses (`control.chain_controller`: commands forwarded at the
driver's next pass, applied at the firmware tick after the round trip's down share, ramped, followed by a first-
order speed loop) to the recorded odometry twists: the round trip's fixed part D (= 2 ``chain.link.delay_s``),
the two ramps and tau (the translation's; the rotation's apart). The twist is linear in the ramped setpoints,
which depend on D only through the tick each command lands on: the cost is piecewise constant in D, so D is
scanned on a 1 ms grid, the ramps and time constants fitted by least squares (scipy) for each distinct landing
of the commands, and the middle of the best interval of D taken (without jitter, the 30 Hz / 50 Hz pattern
leaves cells of T / 5 = 6.7 ms: +-3.3 ms). A fit whose twist residual exceeds 15 % of the excitation's speed is
refused (the robot does not follow the chain model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple, Protocol

import numpy as np
from scipy.optimize import least_squares

from robotino_geom_mpc.arrays import float_triple
from robotino_geom_mpc.control.measurement_times import MeasurementClock
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.model.driver_chain import ChainParams, Firmware, speed_floor

__all__ = ["ChainFit", "Excitation", "IdentifyError", "Recording", "RobotIO", "fit_chain", "run_excitation"]

ZERO = (0.0, 0.0, 0.0)
_ROTATION_SCALE_M = 0.25  # rad/s of rotation weigh like 0.25 m/s of translation in the residual


class IdentifyError(RobotinoError, ValueError):
    """An excitation or fit that cannot identify the chain; the message says why (the robot was stopped)."""


class RobotIO(Protocol):
    """A robot driven through cmd_vel: `poll` waits for the next odometry dispatch."""

    def poll(self) -> tuple[float, list[tuple[float, tuple, tuple]]]:
        """(now [s], the messages since the last poll as (stamp [s], pose, body twist))."""

    def send(self, twist: tuple[float, float, float]) -> None:
        """Publish a cmd_vel now."""


@dataclass(frozen=True)
class Excitation:
    """The excitation's plateaus, probe steps and acceleration limits: the commands never exceed speed + probe,
    rate + probe or the accelerations.
    """

    speed_m_s: float = 0.25
    rate_rad_s: float = 1.0
    acceleration_m_s2: float = 1.0
    acceleration_rad_s2: float = 6.0
    probe_m_s: float = 0.005
    probe_rad_s: float = 0.03

    def segments(self) -> list[tuple[float, tuple[float, float, float], str]]:
        """(start time [s], target twist, check) pieces; check names the axis whose plateau ends there."""
        v, w, pv, pw = self.speed_m_s, self.rate_rad_s, self.probe_m_s, self.probe_rad_s
        return [
            (0.0, ZERO, ""), (0.3, (v, 0.0, 0.0), ""), (1.6, (v + pv, 0.0, 0.0), "x"), (2.0, ZERO, ""),
            (2.8, (0.0, 0.0, w), ""), (3.5, (0.0, 0.0, w + pw), "theta"), (3.9, ZERO, ""),
            (4.6, (0.0, -0.8 * v, 0.0), ""), (5.6, (0.0, -0.8 * v - pv, 0.0), "y"), (6.0, ZERO, ""),
            (6.6, ZERO, "end"),
        ]

    @property
    def duration_s(self) -> float:
        """The excitation's length [s]."""
        return self.segments()[-1][0]

    def command(self, t: float) -> tuple[float, float, float]:
        """The commanded twist at `t` [s]: towards each piece's target at the bounded accelerations."""
        current = [0.0, 0.0, 0.0]
        pieces = self.segments()
        for (start, target, _), (end, _, _) in zip(pieces, pieces[1:] + [(math.inf, ZERO, "")]):
            if t < start:
                break
            span = min(t, end) - start
            for i, limit in enumerate((self.acceleration_m_s2,) * 2 + (self.acceleration_rad_s2,)):
                step = target[i] - current[i]
                current[i] += math.copysign(min(abs(step), limit * span), step)
        return float_triple(current)


class Recording(NamedTuple):
    """What an excitation recorded: the odometry as dispatched and the commands as sent (time, twist)."""

    stamps: np.ndarray  # (m,)
    poses: np.ndarray  # (m, 3)
    twists: np.ndarray  # (m, 3) body
    command_times: np.ndarray  # (k,)
    commands: np.ndarray  # (k, 3)


def _plateau(stamps: list[float], twists: list[tuple], end: float, span: float = 0.15) -> np.ndarray:
    window = [tw for s, tw in zip(stamps, twists) if end - span <= s <= end]
    return np.mean(window, axis=0) if window else np.zeros(3)


def _check(axis: str, commanded: tuple, measured: np.ndarray, ex: Excitation) -> str | None:
    """Why the plateau `measured` (body twist) does not follow `commanded`, or None."""
    i = {"x": 0, "y": 1, "theta": 2}[axis]
    scale = (ex.speed_m_s, ex.speed_m_s, ex.rate_rad_s)
    ratio = measured[i] / commanded[i]
    others = max(abs(measured[j]) / scale[j] for j in range(3) if j != i)
    if abs(measured[i]) < 0.2 * abs(commanded[i]) and others < 0.2:
        return f"no motion: the {axis} speed stayed at {measured[i]:.3g} for a command of {commanded[i]:.3g}"
    if others > 0.2 or ratio < 0.0:
        return (f"the robot does not move as commanded: for {axis} = {commanded[i]:.3g} it moved "
                f"({measured[0]:.3g} m/s, {measured[1]:.3g} m/s, {measured[2]:.3g} rad/s) in base_link")
    if ratio < 0.9:
        return (f"saturation: the {axis} speed levelled off at {measured[i]:.3g}, {100 * ratio:.0f} % of the command "
                f"{commanded[i]:.3g} (motors or the firmware's maxima cannot follow)")
    if ratio > 1.1:
        return (f"the robot does not move as commanded: the {axis} speed {measured[i]:.3g} is {100 * ratio:.0f} % "
                f"of the command {commanded[i]:.3g}")
    return None


def run_excitation(robot: RobotIO, excitation: Excitation = Excitation()) -> Recording:
    """Drive `robot` through `excitation`, checking each plateau; the robot is left commanded to rest.

    Raises
    ------
    IdentifyError
        After stopping the robot: a plateau that shows no motion, saturation or other motion.
    """
    stamps, poses, twists, times, commands = [], [], [], [], []
    checks = [(start, seg_target) for (start, _, check), (_, seg_target, _) in
              zip(excitation.segments()[1:], excitation.segments()) if check]
    start_s = None
    try:
        while True:
            now, messages = robot.poll()
            for stamp, pose, twist in messages:
                stamps.append(stamp)
                poses.append(tuple(pose))
                twists.append(tuple(twist))
            if start_s is None:
                start_s = now
            t = now - start_s
            while checks and t >= checks[0][0]:
                end, target = checks.pop(0)
                for axis, i in (("x", 0), ("y", 1), ("theta", 2)):
                    if target[i]:
                        problem = _check(axis, target, _plateau(stamps, twists, start_s + end), excitation)
                        if problem:
                            raise IdentifyError(f"{problem}; the robot was stopped")
            if t >= excitation.duration_s:
                break
            command = excitation.command(t)
            robot.send(command)
            times.append(now)
            commands.append(command)
    finally:
        robot.send(ZERO)
    if not stamps:
        raise IdentifyError("no odometry arrived during the excitation; the robot was stopped")
    return Recording(np.array(stamps), np.array(poses), np.array(twists), np.array(times), np.array(commands))


@dataclass(frozen=True)
class ChainFit:
    """The identified chain: round trip D [s] and its interval, ramps, tau, the twist residual (RMS, [m/s]).

    tau is the translation's (``chain.speed_loop_time_constant_s``: loops tuned on the translating body);
    the rotation's own (a different inertia behind the same gains) is fitted apart and reported.
    """

    round_trip_s: float
    round_trip_interval_s: tuple[float, float]
    ramp_translation_m_s2: float
    ramp_rotation_rad_s2: float
    speed_loop_time_constant_s: float
    rotation_time_constant_s: float
    residual_rms: float

    def chain(self, prior: ChainParams) -> ChainParams:
        """`prior` with the identified values (``link_delay_s`` = D / 2)."""
        return replace(prior, link_delay_s=0.5 * self.round_trip_s, ramp_translation_m_s2=self.ramp_translation_m_s2,
                       ramp_rotation_rad_s2=self.ramp_rotation_rad_s2,
                       speed_loop_time_constant_s=self.speed_loop_time_constant_s)


class _Model:
    """The chain model's twists at the recording's measurement ticks, for a round trip D."""

    def __init__(self, rec: Recording, prior: ChainParams, round_trip_s: float) -> None:
        p = prior
        clock = MeasurementClock(p.odometry_period_s, p.driver_period_s, 0.5 * round_trip_s, p.link_jitter_s,
                                 p.odometry_dispatch == "latest")
        ticks = round(p.odometry_period_s / p.tick_s)
        index = np.array([clock.update(float(s)).grid_index for s in rec.stamps]) * ticks
        t0 = clock.tick_time(0)
        T = p.driver_period_s
        phase = float(np.median(np.mod(rec.stamps, T)))
        forward = phase + (np.floor((rec.command_times - phase) / T + 1e-9) + 1.0) * T
        apply = np.ceil((forward + 0.5 * round_trip_s - t0) / p.tick_s - 1e-9).astype(int)
        self.prior, self.index, self.first = p, index - index[0], int(index[0])
        self.apply = apply - self.first
        firmware = Firmware(p)
        commands = []
        for c in rec.commands:
            firmware.receive(speed_floor(tuple(c), p), 0.0)
            commands.append(firmware.target)
        order = np.argsort(self.apply, kind="stable")
        self.schedule = [(int(self.apply[i]), commands[i]) for i in order]
        self.measured = rec.twists
        self.v0 = rec.twists[0]

    @property
    def key(self) -> bytes:
        """What D changes: the measurement ticks and the commands' ticks."""
        return self.index.tobytes() + self.apply.tobytes()

    def twists(self, ramp_t: float, ramp_r: float, tau: float, tau_rotation: float) -> np.ndarray:
        """The model's body twists at the measurement ticks.

        `driver_chain.Firmware.tick`'s ramps written out on floats (the loop runs per evaluation of the fit);
        the targets are `Firmware.receive`'s (maxima applied), no timeout (the excitation commands throughout).
        """
        h = self.prior.tick_s
        limit_t, limit_r = ramp_t * h, ramp_r * h
        ex, ew = math.exp(-h / tau), math.exp(-h / tau_rotation)
        schedule, count, k = self.schedule, len(self.schedule), 0
        tx = ty = tw = sx = sy = sw = 0.0
        vx, vy, w = (float(v) for v in self.v0)
        out = []
        for n in range(int(self.index[-1]) + 1):
            out.append((vx, vy, w))
            while k < count and schedule[k][0] <= n:
                tx, ty, tw = schedule[k][1]
                k += 1
            dx, dy = tx - sx, ty - sy
            step = math.hypot(dx, dy)
            if step > limit_t:
                dx, dy = dx * limit_t / step, dy * limit_t / step
            sx, sy, sw = sx + dx, sy + dy, sw + max(-limit_r, min(limit_r, tw - sw))
            vx, vy, w = sx + (vx - sx) * ex, sy + (vy - sy) * ex, sw + (w - sw) * ew
        return np.array(out)[self.index]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        r = self.twists(*x) - self.measured
        r[:, 2] *= _ROTATION_SCALE_M
        return r.ravel()


def _fit_continuous(model: _Model, x0: np.ndarray) -> tuple[np.ndarray, float]:
    result = least_squares(model.residuals, x0, bounds=([0.01, 0.01, 1e-3, 1e-3], [100.0, 1000.0, 1.0, 1.0]),
                           x_scale=x0, diff_step=1e-3)
    return result.x, float(np.sqrt(np.mean(result.fun**2)))


def fit_chain(rec: Recording, prior: ChainParams, excitation: Excitation = Excitation(),
              max_round_trip_s: float = 0.2) -> ChainFit:
    """Fit D, the ramps and tau to a recording (module docstring); `prior` gives the rest of the chain.

    Raises
    ------
    IdentifyError
        A recording too short to fit, or a fit whose residual says the robot does not follow the model.
    """
    if len(rec.stamps) < 20 or len(rec.commands) < 20:
        raise IdentifyError(f"too little data to fit: {len(rec.stamps)} odometry messages, {len(rec.commands)} "
                            "commands")
    tau = prior.speed_loop_time_constant_s
    x0 = np.array([prior.ramp_translation_m_s2, prior.ramp_rotation_rad_s2, tau, tau])
    fits: dict[bytes, tuple[np.ndarray, float]] = {}
    costs = []
    for d in np.arange(0.0, max_round_trip_s + 5e-4, 1e-3):
        model = _Model(rec, prior, float(d))
        if model.key not in fits:
            fits[model.key] = _fit_continuous(model, x0)
            x0 = fits[model.key][0]  # the next landing's fit starts from this one's
        costs.append((d, *fits[model.key]))
    best = min(cost for _, _, cost in costs)
    chosen = [(d, x) for d, x, cost in costs if cost <= best * (1.0 + 1e-9) + 1e-15]
    lo, hi = float(chosen[0][0]), float(chosen[-1][0])
    round_trip = 0.5 * (lo + hi)
    x = chosen[0][1]
    x, rms = _fit_continuous(_Model(rec, prior, round_trip), x)
    if rms > 0.15 * excitation.speed_m_s:
        raise IdentifyError(f"the robot does not follow the chain model: twist residual {rms:.3g} m/s after the fit "
                            f"(more than 15 % of the excitation's {excitation.speed_m_s:g} m/s)")
    return ChainFit(round_trip, (lo, hi), float(x[0]), float(x[1]), float(x[2]), float(x[3]), rms)
