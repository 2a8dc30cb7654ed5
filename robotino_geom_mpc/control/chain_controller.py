"""Tracking through the real Robotino's chain: predict over the command path, plan ramp-respecting velocities.

A controller behind the robocup-logistics driver (`model.driver_chain`) sends body twists on ``cmd_vel`` and
gets odometry stamped when the driver dispatched it. `ChainController.step` takes one such message and:

1. reconstructs its measurement time t_m on the firmware's tick grid (`measurement_times.MeasurementClock`;
   between two grid points that fit, the one where the predicted pose is closest to the measured one);
2. finds when a command sent now acts: the driver forwards it at its next pass (the passes are the stamps'
   grid, s + k T), it arrives d_down later (the round trip's share, ``round_trip_s / 2``) and the firmware
   takes it at the next tick n_a;
3. predicts the state from t_m to tick n_a through the commands already sent, each on its own tick: the
   firmware's ramps and maxima (`driver_chain.Firmware`, replayed on the controller's commands) give the
   setpoint of every tick, and the speed loops follow it as a first-order lag tau (exact over a tick):

       v(t + h) = s + (v(t) - s) e^{-h/tau},   p(t + h) = p(t) + s h + (v(t) - s) tau (1 - e^{-h/tau});   (1)

4. plans the velocity c held from tick n_a (one move over the horizon of H ticks, per odom axis): (1) makes
   the positions affine in c, p_j = a_j + b_j c with a_j = p_0 + v_0 tau (1 - e^{-j h/tau}),
   b_j = j h - tau (1 - e^{-j h/tau}), and c minimises

       sum_{j=1..H} (a_j + b_j c - r_j)^2 + lambda (c - c_prev)^2                                     (2)

   in closed form (r_j the reference at tick n_a + j); its departure d from the reference's velocity is then
   limited so that the ramps can take it back before the error e it closes is overrun (`_braking`):

       d^2 / (2 a) + d t_d <= |e|    (a the ramp, t_d the command path's dead time);                      (3)

   without it a large error (a stop, a gap in the odometry) makes the one-move plan overshoot by the
   ramp's braking distance, again and again. c is turned into base_link at the heading predicted
   halfway through the horizon, then limited to what the ramps let the firmware reach in one tick from its
   setpoint before n_a within the ticks until the next command (a driver period, rounded up to whole ticks:
   the plan respects the ramps; the prediction replays the firmware's ramp tick by tick), and, with the
   driver's speed floor enabled, each component below its floor is set to 0 or to the floor, whichever is nearer
   (so what the firmware gets is what was predicted; the position error this leaves is corrected by the
   next commands, a dither between 0 and the floor).

Nothing here trusts a stamp as a measurement time, and the robot model enters only through tau: the chain
turns the drives into velocity sources.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence

import numpy as np

from robotino_geom_mpc.arrays import float_triple
from robotino_geom_mpc.control.measurement_times import MeasurementClock
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.model.driver_chain import ChainParams, Firmware

__all__ = ["ChainController", "ChainControllerError"]


_BRAKING_SHARE = 0.5  # (3) brakes with half the ramp: the rest takes up the lags the plan does not see
_CHOOSE_MARGIN_M = 5e-4  # a candidate time must fit the measured pose this much better than the clock's pick


class ChainControllerError(RobotinoError, ValueError):
    """A bad setting or measurement (not finite, wrong length), named in the message."""


class ChainController:
    """Delay-compensating velocity MPC through the driver chain (module docstring).

    Parameters
    ----------
    chain
        The controller's knowledge of the chain (identified or the preset): rates, tick, ramps, maxima,
        speed floor, ``speed_loop_time_constant_s``.
    round_trip_s
        The fixed delay driver -> robot -> driver [s]; 2 ``chain.link_delay_s`` if None.
    horizon_ticks
        H of (2).
    move_weight
        lambda of (2) [s^2] (per axis; rad axis alike).
    """

    def __init__(self, chain: ChainParams, round_trip_s: float | None = None, horizon_ticks: int = 4,
                 move_weight: float = 1e-4) -> None:
        rt = 2.0 * chain.link_delay_s if round_trip_s is None else float(round_trip_s)
        if not (math.isfinite(rt) and rt >= 0.0):
            raise ChainControllerError(f"round_trip_s must be finite and >= 0, got {round_trip_s!r}")
        if not (isinstance(horizon_ticks, int) and horizon_ticks >= 1):
            raise ChainControllerError(f"horizon_ticks must be an integer >= 1, got {horizon_ticks!r}")
        self.chain, self.round_trip_s, self.horizon = chain, rt, horizon_ticks
        self.move_weight = float(move_weight)
        self.h, self.tau = chain.tick_s, chain.speed_loop_time_constant_s
        self.ticks_per_sample = round(chain.odometry_period_s / chain.tick_s)
        # the firmware ramps a command over the ticks until the next one arrives (a driver period, whole ticks)
        self.ramp_time_s = math.ceil(chain.driver_period_s / chain.tick_s - 1e-9) * chain.tick_s
        self.clock = MeasurementClock(chain.odometry_period_s, chain.driver_period_s, 0.5 * rt, chain.link_jitter_s,
                                      chain.odometry_dispatch == "latest")
        j = np.arange(1, horizon_ticks + 1) * self.h
        self._decay = self.tau * (1.0 - np.exp(-j / self.tau))
        self._b = j - self._decay
        self._bb = float(self._b @ self._b)
        self.reset()

    def reset(self) -> None:
        """Forget the clock, the commands sent and the last state (robot at rest, no command in flight)."""
        self.clock.reset()
        self.commands: list[tuple[int, tuple[float, float, float]]] = []  # (apply tick, body twist) in order
        self._base: tuple[int, Firmware] | None = None  # the replay's start: a tick and the firmware before it
        self._plan_prev = np.zeros(3)
        self._trajectory: dict[int, tuple[float, float, float]] = {}  # tick -> predicted pose (for the chooser)

    # ------------------------------------------------------------------ the command path model

    def _setpoints(self, first: int, last: int) -> list[tuple[float, float, float]]:
        """The firmware setpoint (body) held after each tick first .. last-1, replayed from the commands."""
        if self._base is None:
            self._base = (first, Firmware(self.chain))
        start, firmware = self._base
        firmware = copy.copy(firmware)
        queue = list(self.commands)
        out = []
        for n in range(min(start, first), last):
            while queue and queue[0][0] <= n:
                firmware.receive(queue.pop(0)[1], n * self.h)
            setpoint = firmware.tick(n * self.h)
            if n >= first:
                out.append(setpoint)
        return out

    def _settle(self, before: int) -> None:
        """Fold the commands applied before tick `before` into the replay's starting firmware state."""
        if self._base is None:
            return  # nothing replayed yet
        start, firmware = self._base
        if before <= start:
            return
        firmware = copy.copy(firmware)
        for n in range(start, before):
            while self.commands and self.commands[0][0] <= n:
                firmware.receive(self.commands.pop(0)[1], n * self.h)
            firmware.tick(n * self.h)
        self._base = (before, firmware)

    def _propagate(self, pose: list[float], velocity: list[float], setpoints: list) -> tuple[list, list]:
        """(1) over one tick per setpoint; velocity in odom; returns the pose and velocity after them."""
        e = math.exp(-self.h / self.tau)
        g = self.tau * (1.0 - e)
        x, y, th = pose
        vx, vy, w = velocity
        for sx, sy, sw in setpoints:
            heading = th + 0.5 * self.h * (sw + (w - sw) * g / self.h)
            c, s = math.cos(heading), math.sin(heading)
            ox, oy = c * sx - s * sy, s * sx + c * sy
            x += ox * self.h + (vx - ox) * g
            y += oy * self.h + (vy - oy) * g
            th += sw * self.h + (w - sw) * g
            vx, vy, w = ox + (vx - ox) * e, oy + (vy - oy) * e, sw + (w - sw) * e
        return [x, y, th], [vx, vy, w]

    # ------------------------------------------------------------------ one message

    def step(self, stamp_s: float, pose: tuple[float, float, float], twist: tuple[float, float, float],
             reference: Callable[[np.ndarray], np.ndarray], now_s: float | None = None) -> tuple[float, float, float]:
        """The cmd_vel (v_x, v_y, theta') in base_link for one odometry message.

        Parameters
        ----------
        stamp_s
            The message's stamp (the driver's dispatch time) [s].
        pose, twist
            Its pose (x, y, theta) in odom and twist in base_link.
        reference
            Positions (x_d, y_d, theta_d) at an array of times [s] (shape (n, 3)).
        now_s
            When the command will reach the driver; `stamp_s` if None.
        """
        values = [float(v) for v in (*pose, *twist)] if len(pose) == 3 and len(twist) == 3 else []
        if len(values) != 6 or not all(math.isfinite(v) for v in values):
            raise ChainControllerError(f"pose and twist must be three finite numbers each, got {pose!r}, {twist!r}")
        now = stamp_s if now_s is None else float(now_s)
        measured = self.clock.update(stamp_s, self._chooser(values[:3]))
        h = self.h
        t0 = self.clock.tick_time(0)
        n_m = measured.grid_index * self.ticks_per_sample
        n_a = max(self._apply_tick(now), n_m + 1)
        c, s = math.cos(values[2]), math.sin(values[2])
        v_odom = [c * values[3] - s * values[4], s * values[3] + c * values[4], values[5]]
        setpoints = self._setpoints(n_m, n_a + self.horizon)
        p_a, v_a = self._propagate(values[:3], v_odom, setpoints[: n_a - n_m])
        self._remember(n_m, values[:3], v_odom, setpoints)
        times = t0 + (n_a + np.arange(0, self.horizon + 1)) * h
        r = np.array(reference(times), dtype=float)
        r[:, 2] = p_a[2] + np.angle(np.exp(1j * (r[:, 2] - p_a[2])))  # the nearest turn of the heading
        a = np.asarray(p_a)[None, :] + np.outer(self._decay, v_a)
        plan = (self._b @ (r[1:] - a) + self.move_weight * self._plan_prev) / (self._bb + self.move_weight)
        plan = self._braking(plan, (r[-1] - r[0]) / (self.horizon * h), r[0] - np.asarray(p_a))
        self._plan_prev = plan
        heading = p_a[2] + 0.5 * self.horizon * h * plan[2]
        c, s = math.cos(heading), math.sin(heading)
        body = (c * plan[0] + s * plan[1], -s * plan[0] + c * plan[1], float(plan[2]))
        command = self._feasible(body, setpoints[n_a - n_m - 1] if n_a - n_m - 1 >= 0 else (0.0, 0.0, 0.0))
        self.commands = [cmd for cmd in self.commands if cmd[0] < n_a] + [(n_a, command)]
        self._settle(n_m - 4 * self.ticks_per_sample)
        return command

    def _braking(self, plan: np.ndarray, v_ref: np.ndarray, error: np.ndarray) -> np.ndarray:
        """`plan` with its departure from the reference velocity limited to what the ramps can take back (3).

        A departure d closes an error e at most as fast as the ramp a can return the velocity to the
        reference's within e, the dead time t_d (a driver period in whole ticks, the round trip, tau) included:
        d^2 / (2 a) + d t_d <= |e|, so |d| <= a (sqrt(t_d^2 + 2 |e| / a) - t_d). Translation as a vector.
        """
        t_d = self.ramp_time_s + self.round_trip_s + self.tau
        out = plan.copy()
        ramps = ((slice(0, 2), self.chain.ramp_translation_m_s2), (slice(2, 3), self.chain.ramp_rotation_rad_s2))
        for axes, ramp in ramps:
            departure = plan[axes] - v_ref[axes]
            size = float(np.linalg.norm(departure))
            a = _BRAKING_SHARE * ramp
            limit = a * (math.sqrt(t_d**2 + 2.0 * float(np.linalg.norm(error[axes])) / a) - t_d)
            if size > limit:
                out[axes] = v_ref[axes] + departure * (limit / size)
        return out

    def _apply_tick(self, now_s: float) -> int:
        """The firmware tick a command reaching the driver at `now_s` acts from: forwarded at the driver's next
        pass (the grid of the stamps), the round trip's down share later, at the next tick.
        """
        T, stamp = self.chain.driver_period_s, self.clock.last_stamp_s
        forward = stamp + (math.floor((now_s - stamp) / T + 1e-9) + 1) * T
        return math.ceil((forward + 0.5 * self.round_trip_s - self.clock.tick_time(0)) / self.h - 1e-9)

    def note_command(self, now_s: float, twist: tuple[float, float, float]) -> None:
        """A command someone else sent at `now_s` (a zero twist of the node's refusals or watchdog): the
        firmware gets it, so the prediction takes it from its tick on. Before the first odometry: nothing.
        """
        if self.clock.index < 0:
            return
        n_a = self._apply_tick(now_s)
        self.commands = [cmd for cmd in self.commands if cmd[0] < n_a] + [(n_a, float_triple(twist))]

    def _feasible(self, body: tuple[float, float, float], setpoint: tuple[float, float, float]) -> tuple:
        """`body` within the ramps' reach of `setpoint` until the next command, the maxima and the floor's gaps."""
        p = self.chain
        dx, dy = body[0] - setpoint[0], body[1] - setpoint[1]
        step, limit = math.hypot(dx, dy), p.ramp_translation_m_s2 * self.ramp_time_s
        if step > limit:
            dx, dy = dx * limit / step, dy * limit / step
        limit = p.ramp_rotation_rad_s2 * self.ramp_time_s
        vx, vy = setpoint[0] + dx, setpoint[1] + dy
        w = setpoint[2] + max(-limit, min(limit, body[2] - setpoint[2]))
        speed = math.hypot(vx, vy)
        if speed > p.max_translation_m_s:
            vx, vy = vx * p.max_translation_m_s / speed, vy * p.max_translation_m_s / speed
        w = max(-p.max_rotation_rad_s, min(p.max_rotation_rad_s, w))
        if p.speed_floor == "disabled":
            return (vx, vy, w)
        floors = (p.speed_floor_translation_m_s,) * 2 + (p.speed_floor_rotation_rad_s,)
        return tuple(0.0 if abs(v) < 0.5 * f else (math.copysign(f, v) if abs(v) < f else v)
                     for v, f in zip((vx, vy, w), floors))

    def _remember(self, n_m: int, pose: list, v_odom: list, setpoints: list) -> None:
        """The predicted pose at the next few ticks after this measurement (for the next message's chooser)."""
        self._trajectory = {}
        p, v = pose, v_odom
        for k, sp in enumerate(setpoints[: 4 * self.ticks_per_sample]):
            p, v = self._propagate(p, v, [sp])
            self._trajectory[n_m + k + 1] = tuple(p)

    def _chooser(self, pose: list[float]) -> Callable[[Sequence[float]], int] | None:
        """Between candidate measurement times, the one whose predicted pose is clearly nearest ``pose``."""
        if not self._trajectory:
            return None
        t0 = self.clock.tick_time(0)

        def choose(times: Sequence[float]) -> int:
            costs = []
            for t in times:
                predicted = self._trajectory.get(round((t - t0) / self.h))
                costs.append(math.inf if predicted is None else math.hypot(predicted[0] - pose[0],
                                                                           predicted[1] - pose[1]))
            default = len(costs) - 1 if self.clock.newest else 0  # the clock's own pick
            best = int(np.argmin(costs))
            # another only when the pose says so clearly: the model's error must not override the count
            clear = costs[best] < 0.5 * costs[default] and costs[default] - costs[best] > _CHOOSE_MARGIN_M
            return best if math.isfinite(costs[best]) and clear else default
        return choose
