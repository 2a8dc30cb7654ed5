"""Delay-compensated, packetized MPC: from an aged odometry, a plan of commands that act at known robot times.

An off-board controller sees each odometry late and its commands act later
still. `DelayCompensatingController` wraps `motion_controller.MotionController`
(which is unchanged; without a link it is used as it is): for the odometry
stamped t_m (robot clock) it

1. filters the measured pose at t_m (`estimator.OdometryFilter`, the time
   constant of ``control.odometry_filter_time_constant_s``; dt from stamps);
2. predicts the state at the plan's first action time t_a = t_m + lead Ts
   through the commands the robot applies over [t_m, t_a): those of the plans
   already sent, chosen as the robot's `network.plan.PlanBuffer` chooses;
3. rolls the MotionController out over M = ``control.plan_length`` periods
   from the predicted state, each step from the state predicted under the
   previous one, and returns the `network.plan.CommandPlan` of the M commands
   (voltages; with ``command_interface="cmd_vel"`` the twists of
   `MotionController.next_velocity`), entry j acting from t_a + j Ts.

The model of steps 2 and 3 is the MPC's own per-axis model, eq. (49):
x(k+1) = A_d x(k) + B_d u(k) in the odom frame, u(k) the accelerations the
controller meant by the command (`ControlOutput.u` as applied: scaled by the
current limit, or those of clipped voltages). It is the model the MPC already
predicts with (eq. 50), so a plan made from a predicted state is the plan the
undelayed loop would make from that state (exact for lead 0), costs six
multiply-adds per period, and needs no motor currents, which no odometry
measures; the drives' current dynamics (L/R, 1.5 ms on a Robotino 3) and the
heading's turn within a period are what it leaves out (the inverse drive
already aims the period-mean current at u). Over a lead of 0.1-0.3 s a model
error matters far more than in the undelayed loop (a 20 % mass error moves
the prediction by 0.1 g u lead^2, millimetres, and the loop with it), so the
prediction takes the robot's acceleration as g u - c v per axis, with the
input gain g and extra damping c fitted to the measured velocities under the
reported commands (`_observe`; g = 1, c = 0 for an exact model). A period for
which the robot had no plan (exhaustion: zero volts) is predicted with u = 0.
Between two odometries more than a period apart (lost or overtaken on the
up-link) the pose filter's trapezoid is corrected with the velocities of the
same model under the commands applied.

What the robot applies is not guessed: it reports per period what it applied
(`report_applied`) and per plan when it received it (`report_receipt`), in its
own clock. Plans are then known received (from their receipt), known not
received by a time (a period at or after their first entry ran an older plan
or none: taken as lost), or in flight (assumed to arrive by their first
entry, which the lead makes true for its quantile of the round trips). The
round trip of a plan, receipt - basis, needs no clock but the robot's; the
lead is ``control.lead_quantile`` of the recent round trips in periods,
rounded up, within [``control.lead_min_periods``, ``control.lead_max_periods``].
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from robotino_geom_mpc.arrays import float_triple
from robotino_geom_mpc.control.estimator import OdometryFilter, filter_gain
from robotino_geom_mpc.control.motion_controller import ControllerInputError, MotionController
from robotino_geom_mpc.model.speed_loop import SPEED_LOOP_TIME_CONSTANT_S
from robotino_geom_mpc.control.plan_history import PlanHistory, SentPlan
from robotino_geom_mpc.network.plan import TIME_TOLERANCE_S, CommandPlan
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams

__all__ = ["GAIN_BOUNDS", "GAIN_PRIOR_WEIGHT", "GAIN_TIME_CONSTANT_S", "PLAN_CURRENT_MARGIN",
           "DelayCompensatingController", "LinkStatistics"]

GAIN_TIME_CONSTANT_S = 10.0
"""Memory of the input gain estimate g [s] (the model's mass and yaw inertia error)."""

GAIN_PRIOR_WEIGHT = 1.0
"""Weight of the prior (g, c) = (1, 0) in the fit's sums [(m/s^2)^2, (m/s)^2]: 100 periods at 0.1 m/s^2."""

GAIN_BOUNDS = (0.5, 2.0)
"""The input gain estimate stays within these (a model off by more is not this controller's to rescue)."""

_ZERO = (0.0, 0.0, 0.0)
_REPORT_WAIT_PERIODS = 5  # a period between two odometries waits this long for its report before it is skipped

PLAN_CURRENT_MARGIN = 0.93
"""The voltage plans' current limit over ``control.current_limit_a``: a plan's voltages are made for predicted
states, and at the true state (a prediction error moves the back-EMF) they drive another current; 7 % kept the
``robustness`` scenario over a 30 + 20 ms, 10 % link within the limit (0.83 A for 0.86 A, 0.89 A without).
Twist plans (``cmd_vel``) keep the limit as it is, as the undelayed controller does: the robot's speed loops
turn a twist into voltages at the true state, so no back-EMF is mispredicted, and the limit acts on the
controller model's currents, not the robot's. With the ``robustness`` model (mass x1.2, friction x2) those read
0.86 A at the ramp-in while the robot draws 0.28 A; the margin throttled the plans' acceleration there for
0.9 s, the robot fell 9 mm behind (1.65 mm RMS over that link, 0.55 mm without the margin)."""

@dataclass(frozen=True)
class LinkStatistics:
    """The link as the controller sees it, from the robot's stamps and reports (robot clock).

    Attributes
    ----------
    round_trip_mean_s, round_trip_jitter_s, round_trip_quantile_s
        Mean, standard deviation and the lead's quantile of the recent round trips (receipt - basis) [s].
    lead_periods
        The lead of the last plan [periods].
    plans_sent, plans_received, plans_lost
        Plans sent; reported received; known not received (taken as lost).
    odometry_received, odometry_missing, odometry_stale
        Odometries taken; stamps skipped between them (lost on the up-link); odometries older than one taken.
    exhausted_periods
        Reported periods in which the robot had no plan (zero command).
    """

    round_trip_mean_s: float
    round_trip_jitter_s: float
    round_trip_quantile_s: float
    lead_periods: int
    plans_sent: int
    plans_received: int
    plans_lost: int
    odometry_received: int
    odometry_missing: int
    odometry_stale: int
    exhausted_periods: int


class DelayCompensatingController:
    """The plan-making controller of an off-board link: predicts to the time of action, rolls the MPC out.

    Parameters
    ----------
    robot
        The controller's model of the robot.
    control
        As for `MotionController`, plus ``plan_length`` (M), ``lead_min_periods``, ``lead_max_periods``
        and ``lead_quantile``.
    command_interface
        ``voltages`` (entries are wheel voltages [V]) or ``cmd_vel`` (body twists in base_link).

    Notes
    -----
    `plan` needs the reference at t_m + i Ts for i = 1 .. `preview_length` (the last rollout step's
    horizon at the largest lead). Cost per odometry: M `MotionController.step` calls plus the
    prediction's lead + M model steps (eq. 49).
    """

    def __init__(self, robot: RobotinoParams, control: ControlParams, command_interface: str = "voltages") -> None:
        if command_interface not in ("voltages", "cmd_vel"):
            raise ControllerInputError(f"command_interface must be 'voltages' or 'cmd_vel', got {command_interface!r}")
        if control.lead_max_periods < control.lead_min_periods:
            raise ControllerInputError(f"control.lead_max_periods ({control.lead_max_periods}) must be >= "
                                       f"control.lead_min_periods ({control.lead_min_periods})")
        self.control = control
        self.command_interface = command_interface
        self.period_s = float(control.period_s)
        self.plan_length = int(control.plan_length)
        self.horizon = int(control.horizon)
        margin = PLAN_CURRENT_MARGIN if command_interface == "voltages" else 1.0
        self.inner = MotionController(robot, replace(control, odometry_filter_time_constant_s=0.0,
                                                     current_limit_a=margin * control.current_limit_a))
        tau = float(control.odometry_filter_time_constant_s)
        self.estimator = OdometryFilter(self.period_s, tau, control.odometry_twist) if tau > 0.0 else None
        self._period_mean = control.odometry_twist == "period_mean"
        self._cmd_vel = command_interface == "cmd_vel"
        self._A = self.inner.mpc.A_d.tolist()
        self._B = self.inner.mpc.B_d.tolist()
        self.reset()

    @property
    def preview_length(self) -> int:
        """Rows of reference `plan` needs: at t_m + Ts .. t_m + (lead_max + M - 1 + N) Ts."""
        return int(self.control.lead_max_periods) + self.plan_length - 1 + self.horizon

    def reset(self) -> None:
        """Forget plans, reports, round trips and the filter (robot at rest, drives off)."""
        self.inner.reset()
        if self.estimator is not None:
            self.estimator.reset()
        memory_s = 2.0 * (self.control.lead_max_periods + self.plan_length) * self.period_s
        self.history = PlanHistory(self.period_s, self.control.lead_quantile, memory_s)
        self._last_stamp: float | None = None
        self._previous: list[float] | None = None  # the last odometry taken
        self._unobserved: deque[tuple[list[float], list[float], int]] = deque()  # periods awaiting their report
        self._gains = [(1.0, 0.0)] * 3  # per axis (g, c): the robot's acceleration is g u - c v
        self._fit_sums = [[0.0] * 5, [0.0] * 5]  # the weighted sums of the fit, translation and rotation
        self._odometry = self._missing = self._stale = 0
        self._lead = self._plan_lead = int(self.control.lead_min_periods)
        self.prediction: tuple[float, tuple[float, ...]] | None = None  # (t_a, the state predicted at t_a)

    def start_at(self, x: float, y: float, theta: float) -> None:
        """Start the pose filter at a known pose of the robot at rest (as `MotionController.start_at`)."""
        if self.estimator is not None:
            self.estimator.start_at(x, y, theta)

    # --- the robot's reports (`PlanHistory`) ---------------------------------------------------------------------

    def report_receipt(self, basis_s: float, received_s: float, taken: bool = True) -> None:
        """The robot received the plan of basis `basis_s` at its time `received_s`; its buffer `taken` it or not."""
        self.history.report_receipt(basis_s, received_s, taken)

    def report_applied(self, time_s: float, basis_s: float | None, index: int = 0) -> None:
        """The robot applied entry `index` of plan `basis_s` from its time `time_s` (None: no plan, zero command)."""
        self.history.report_applied(time_s, basis_s, index)

    # --- planning -------------------------------------------------------------------------------------------------

    def _choose_lead(self) -> int:
        """The lead of the next plan: the round trips' quantile in periods, rounded up, within the bounds."""
        if self.history.round_trips:
            lead = math.ceil(self.history.round_trip_quantile() / self.period_s - 1e-6)
        else:  # before any round trip is measured the plans wait: none acts late, on a robot that has not moved
            lead = int(self.control.lead_max_periods)
        # a lead grows by at most half a plan per plan, so the plans sent before still cover up to the new first entry
        self._lead = min(lead, self._lead + self.plan_length // 2) if self.history.sent else lead
        return min(max(self._lead, int(self.control.lead_min_periods)), int(self.control.lead_max_periods))

    def plan(self, stamp_s: float, X: object, preview: object) -> CommandPlan | None:
        """The plan for the odometry X = (x, x', y, y', theta, theta') stamped `stamp_s` (robot clock).

        Parameters
        ----------
        stamp_s
            The odometry's stamp [s].
        X
            The measured body state (eq. 2), shape (6,).
        preview
            The reference positions at stamp_s + i Ts, i = 1 .. `preview_length`, shape (preview_length, 3).

        Returns
        -------
        CommandPlan or None
            None for an odometry not newer than one already taken (reordered or duplicated on the link).

        Raises
        ------
        ControllerInputError
            For a bad X or preview (nothing changes).
        """
        Ts, M, N = self.period_s, self.plan_length, self.horizon
        x = np.asarray(X, dtype=float)
        Y = np.asarray(preview, dtype=float)
        if x.shape != (6,) or not np.isfinite(x).all():
            raise ControllerInputError(f"X must be 6 finite numbers, got {X!r}")
        if Y.shape != (self.preview_length, 3) or not np.isfinite(Y).all():
            raise ControllerInputError(f"preview must be finite with shape ({self.preview_length}, 3), got {Y.shape}")
        if self._last_stamp is not None and stamp_s <= self._last_stamp + TIME_TOLERANCE_S:
            self._stale += 1
            return None
        dt, gap = None, 1
        if self._last_stamp is not None:
            gap = round((stamp_s - self._last_stamp) / Ts)
            self._missing += max(gap - 1, 0)
            interval = stamp_s - self._last_stamp
            dt = None if gap == 1 and abs(interval - Ts) < TIME_TOLERANCE_S else interval
        self._last_stamp = stamp_s
        self._odometry += 1
        state = x.tolist()
        period0 = self.history.period(stamp_s)
        newest_first = self.history.newest_first()
        if self.estimator is not None:
            px, vx, py, vy, theta, w = state
            state[0], state[2], state[4] = self.estimator.update(px, vx, py, vy, theta, w, dt)
            if dt is not None and self._previous is not None and not self._period_mean:
                shift = self._interpolation_gain(dt) * self._trapezoid_error(self._previous, state, period0 - gap, gap,
                                                                              newest_first)
                self.estimator.shift(*shift.tolist())
                state[0], state[2], state[4] = (np.array(state)[[0, 2, 4]] + shift).tolist()
        if self._previous is not None and gap == 1 and not self._cmd_vel:
            self._unobserved.append((self._previous, x.tolist(), period0 - 1))
        self._observe_reported(period0, newest_first)
        self._previous = x.tolist()
        lead = self._plan_lead = self._choose_lead()
        u_last, currents = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        for j in range(lead):  # step 2: through the commands applied over [t_m, t_a)
            command = self.history.command(period0 + j, newest_first)
            u_last, currents, entry = command if command is not None else ([0.0] * 3, [0.0] * 3, _ZERO)
            state = self._advance(state, u_last, entry)
        if lead == 0:
            command = self.history.command(period0 - 1, newest_first)
            if command is not None:
                u_last, currents, _ = command
        self.prediction = (stamp_s + lead * Ts, tuple(state))
        self.inner.restart_from(u_last, currents)
        entries: list[tuple[float, float, float]] = []
        us, ends = [], []
        for j in range(M):  # step 3: the rollout from the predicted state
            out = self.inner.step(tuple(state), Y[lead + j: lead + j + N])
            entries.append(float_triple(out.voltages) if self.command_interface == "voltages"
                           else self.inner.next_velocity())
            u = self.inner.u_prev.tolist()
            us.append(u)
            ends.append(self.inner.drive.current_estimate)
            state = self._advance(state, u, entries[-1])
        t_a = stamp_s + lead * Ts
        plan = CommandPlan(stamp_s, tuple(t_a + j * Ts for j in range(M)), tuple(entries), Ts)
        self.history.add(plan, us, ends)
        return plan

    def stop_plan(self, basis_s: float) -> CommandPlan:
        """A plan of zeros of basis `basis_s` (robot clock; a disabled tick's odometry stamp, or just after the
        newest planned from) from the earliest period a plan can act in, basis + ``lead_min_periods`` Ts, to the end
        of the latest a plan of an odometry up to it can reach, basis + (``lead_max_periods`` + `plan_length`) Ts:
        newer than every plan sent and outlasting them, it replaces them on the robot, which stops instead of
        playing out what it holds. Not kept in the history (an enable or a restart resets it); the robot's reports
        of it read as no plan (zero).
        """
        first, end = int(self.control.lead_min_periods), int(self.control.lead_max_periods) + self.plan_length
        times = tuple(basis_s + j * self.period_s for j in range(first, end))
        return CommandPlan(basis_s, times, (_ZERO,) * len(times), self.period_s)

    def statistics(self) -> LinkStatistics:
        """The link as seen so far (`LinkStatistics`)."""
        h = self.history
        trips = np.fromiter(h.round_trips, float)
        return LinkStatistics(
            round_trip_mean_s=float(trips.mean()) if trips.size else math.nan,
            round_trip_jitter_s=float(trips.std()) if trips.size else math.nan,
            round_trip_quantile_s=h.round_trip_quantile(),
            lead_periods=self._plan_lead,
            plans_sent=h.sent,
            plans_received=h.received,
            plans_lost=h.lost,
            odometry_received=self._odometry,
            odometry_missing=self._missing,
            odometry_stale=self._stale,
            exhausted_periods=h.exhausted,
        )

    # --- internals ------------------------------------------------------------------------------------------------

    def _interpolation_gain(self, dt: float) -> float:
        """1 - L(dt): the share of the predicted pose the filter keeps over an interval dt."""
        return 1.0 - filter_gain(dt, self.control.odometry_filter_time_constant_s)

    def _trapezoid_error(self, previous: list[float], state: list[float], period: int, gap: int,
                         newest_first: list[SentPlan]) -> np.ndarray:
        """What the filter's trapezoid (one over the whole gap) misses of the displacement (x, y, theta) over
        `gap` periods from robot period `period` on: the velocities at each period boundary from eq. (49) under
        the commands applied, corrected linearly to end at the measured one (so only their shape is the model's).
        """
        if gap < 2:
            return np.zeros(3)
        velocities = [[previous[1], previous[3], previous[5]]]
        s = list(previous)
        for j in range(gap):
            command = self.history.command(period + j, newest_first)
            s = self._advance(s, *(command[0::2] if command is not None else (_ZERO, _ZERO)))
            velocities.append([s[1], s[3], s[5]])
        v = np.array(velocities)
        v += np.outer(np.arange(gap + 1) / gap, np.array(state)[[1, 3, 5]] - v[-1])
        interpolated = 0.5 * self.period_s * (v[:-1] + v[1:]).sum(axis=0)
        return interpolated - 0.5 * gap * self.period_s * (v[0] + v[-1])

    def _observe_reported(self, period0: int, newest_first: list[SentPlan]) -> None:
        """`_observe` the periods between two odometries whose command the robot has reported, oldest first.

        A period waits for its report (the report and the next odometry travel together, but a receiver may take
        them in either order) up to `_REPORT_WAIT_PERIODS`; one whose report was lost is skipped: an assumed
        command (a plan in flight taken as arrived) that did not run would bias the fit.
        """
        while self._unobserved:
            previous, measured, period = self._unobserved[0]
            if self.history.reported(period):
                self._observe(previous, measured, period, newest_first)
            elif period >= period0 - _REPORT_WAIT_PERIODS:
                return
            self._unobserved.popleft()

    def _observe(self, previous: list[float], measured: list[float], period: int,
                 newest_first: list[SentPlan]) -> None:
        """Update the input gain g and extra damping c from one period between two odometries.

        Per axis y = (v(k+1) - A_d[1,1] v(k)) / B_d[1] is the acceleration the robot took under the command's u
        and its velocity v(k); (g, c) of each group (translation: x and y together, mass and body friction;
        rotation: yaw inertia and friction) is the least-squares fit y = g u - c v over the periods weighted by
        exp(-age / `GAIN_TIME_CONSTANT_S`), with a prior of weight `GAIN_PRIOR_WEIGHT` at (1, 0); g within
        `GAIN_BOUNDS`. Only a single period (gap 1) whose command was reported counts.
        """
        command = self.history.command(period, newest_first)
        if command is None:
            return
        u = command[0]
        decay = math.exp(-self.period_s / GAIN_TIME_CONSTANT_S)
        for group, axes in enumerate(((0, 1), (2,))):
            sums = [decay * value for value in self._fit_sums[group]]  # uu, uv, vv, yu, yv
            for a in axes:
                a11, b1 = self._A[a][1][1], self._B[a][1]
                v = previous[2 * a + 1]
                y = (measured[2 * a + 1] - a11 * v) / b1
                for n, value in enumerate((u[a] * u[a], u[a] * v, v * v, y * u[a], y * v)):
                    sums[n] += value
            self._fit_sums[group] = sums
            uu, uv, vv, yu, yv = sums
            w = GAIN_PRIOR_WEIGHT
            # normal equations of min sum (y - g u + c v)^2 + w (g - 1)^2 + w c^2
            det = (uu + w) * (vv + w) - uv * uv
            g = ((yu + w) * (vv + w) - yv * uv) / det
            c = ((yu + w) * uv - yv * (uu + w)) / det
            for a in axes:
                self._gains[a] = (min(max(g, GAIN_BOUNDS[0]), GAIN_BOUNDS[1]), c)

    def _advance(self, state: list[float], u: Sequence[float], entry: Sequence[float]) -> list[float]:
        """One period of eq. (49) per axis: (p, v) <- A_d (p, v) + B_d (g u - c v), g and c the estimates.

        With the cmd_vel interface the robot's wheel-speed loops, not u, set the motion: the velocity goes to
        the commanded twist (`entry`, base_link, rotated at the mid-period heading) as a first-order lag of
        the loops' time constant `SPEED_LOOP_TIME_CONSTANT_S`, the position with it.
        """
        out = list(state)
        if self._cmd_vel:
            Ts, tau = self.period_s, SPEED_LOOP_TIME_CONSTANT_S
            keep = math.exp(-Ts / tau)
            vx, vy, w = entry
            heading = state[4] + 0.5 * Ts * w
            c, s = math.cos(heading), math.sin(heading)
            for a, target in enumerate((c * vx - s * vy, s * vx + c * vy, w)):
                p, v = state[2 * a], state[2 * a + 1]
                out[2 * a] = p + target * Ts + (v - target) * tau * (1.0 - keep)
                out[2 * a + 1] = target + (v - target) * keep
            return out
        for a in range(3):
            (a00, a01), (a10, a11) = self._A[a]
            b0, b1 = self._B[a]
            g, c = self._gains[a]
            p, v = state[2 * a], state[2 * a + 1]
            ua = g * u[a] - c * v
            out[2 * a], out[2 * a + 1] = a00 * p + a01 * v + b0 * ua, a10 * p + a11 * v + b1 * ua
        return out
