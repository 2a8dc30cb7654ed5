"""The controller's tick protocol as one plain object: inputs in, what to send out (no rclpy, time handed in).

`ControllerLoop` is what the controller node (`nodes.controller_node`), the replay (`recording.regress`,
`regress_plans`, `regress_chain`) and the offline loops drive: each input (`loop.events`: an `Odometry`, a
`Preview`, a robot's `AppliedReport`, an `Undecodable` one, ``~/enable``, the watchdog's timer, new parameters,
the stop) goes in with the time (`Now`), and the loop answers with the list of outputs to send: the command
(`Command`: wheel voltages [V] or a base_link twist), a plan (`PlanOut`), zero with a reason (`Zero`), the
diagnostics, the predicted path, log lines.

Each odometry is one control tick: one `control.motion_controller.MotionController.step` (three MPCs, eq. 56 ->
T(theta), eqs. 33-37 -> inverse drive) on the odometry's state (eq. 2) and the preview paired with it, moved to
its stamp (`reference.trajectories.preview_at`: a longer preview's rows of the periods elapsed, then to second
order), the step's ``dt_s`` the interval since the last odometry used
(`step_interval`). The pairing is the one difference between the modes, an object chosen at construction:

* `RealtimePairing`: the freshest preview; stamps are checked against the clock handed in (``stale``,
  ``future``); the watchdog gives zero and a bumpless restart; disabled, every odometry is answered with zero.
* `LockstepPairing`: the preview of the odometry's own stamp (an odometry waits for it; odometries are
  answered in arrival order; a refused preview gives its tick zero); the plant holds the time, so the watchdog
  only says what is missing; a resent tick asks for the answers still held to go out (`Resend`); tick t = 0 starts robot
  and reference together as `offline.simulation.simulate` does.

Refusals (zero, an ERROR diagnostic with the reason key, counted): the input checks of `loop.inputs`
(``non_finite``, ``size``, ``quaternion_norm``, ``quaternion_tilt``, ``stamp``, ``malformed``), ``implausible``
(`MotionController.state_problem`, a preview position beyond `MAX_POSITION_M`), ``frame`` (a preview not in
the loop's odom frame), ``stale`` / ``future`` (realtime), ``preview_<reason>`` (lockstep: the preview of the
tick was refused), ``controller`` (the step refused its inputs), ``internal_error`` (a bug: zero and a restart).
Dropped (counted, a WARN diagnostic, no output): a ``duplicate`` or ``old`` stamp.

One reference source at a time (`loop.source_pairing.SourcePairing`, lease ``reference_timeout_s`` on the watchdog's
clock): a preview whose `Preview.source` is not the paired one's while that one's previews are fresh is refused
before any check (``refused_second_source`` counted in every status; no zero, nothing else touched: the loop goes on
with its paired source); the paired source stale, the next one takes the lease (its reference jump restarts the
tracking bumplessly).

Bumpless (re)start (`control.blend.BlendEngagement`): at the first tick, after the watchdog, at ``enable``, at a
preview whose reference jumped (more than ``reference_jump_m`` / ``reference_jump_rad`` from the previous
preview moved to its stamp) and after new parameters: the controller is reset
and a C^3 offset takes the reference from the measured state to itself.

Plans (``plans``: an off-board controller over a link): per odometry a `network.plan.CommandPlan` of
`control.delay_compensation.DelayCompensatingController`, the robot's reports (receipts and applied periods)
handed to it in the order they came (lockstep: those that came while an odometry waited are held until it is
planned), a report further than `REPORT_WINDOW_S` from the newest odometry refused.

The chain (``chain``: the controller through the real driver's chain, realtime, cmd_vel): each odometry steps a
`control.chain_tracking.ChainTracker` with the newest preview at the clock handed in; duplicate and old-looking
stamps are used (dispatch times); every zero sent is noted in its command model; each tick's diagnostic
(message ``chain``) names the preview used (``preview_stamp_ns``). Every status, in every mode, carries the clock
handed in (``clock_ns``) and the one handed in with the newest preview it took (``preview_clock_ns``; empty before
any), so that a recording replays in the node's order at the node's times: a node that fell behind took a preview
later than its publication, and its age at a tick (``reference_timeout_s``) counts from then.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, Protocol

import numpy as np

from robotino_geom_mpc.control.blend import ANGULAR_LIMIT_RADPS2, LINEAR_LIMIT_MPS2, BlendEngagement, BlendError
from robotino_geom_mpc.control.chain_controller import ChainControllerError
from robotino_geom_mpc.control.chain_tracking import ChainTracker
from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController
from robotino_geom_mpc.control.motion_controller import (MAX_POSITION_M, ControlOutput, ControllerInputError,
                                                         MotionController, step_interval)
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.loop.events import (AppliedReport, Command, Diagnostic, EnabledChanged, Level, Log, Now,
                                           Odometry, Output, PlanarOdometry, PlanarPreview, PlanOut, PredictedPath,
                                           Preview, Resend, Undecodable, Waiting, Zero)
from robotino_geom_mpc.loop.source_pairing import SourcePairing
from robotino_geom_mpc.loop.inputs import (PLANAR_POINT_SIZE, POINT_SIZE, QUATERNION_NORM_TOLERANCE, REPORT_WINDOW_S,
                                           TILT_TOLERANCE_RAD, InputCounters, InputRejected, planar_preview_arrays,
                                           planar_state, preview_of_values, report_problem, stamp_problem,
                                           state_of_odometry)
from robotino_geom_mpc.model.driver_chain import ChainParams
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.reference.trajectories import preview_at, whole_periods

__all__ = ["ControllerLoop", "EVERYONE", "LINK_KEYS", "Listeners", "LockstepPairing", "LoopConfigError",
           "LoopSettings", "QUIET", "RealtimePairing", "TRACKING_KEYS"]

TRACKING_KEYS = ("error_x_m", "error_y_m", "error_theta_rad", "compute_time_ms", "saturated", "infeasible",
                 "preview_stamp_ns", "dt_s")
_EVENT_KEYS = ("watchdog", *InputCounters.KEYS, "blend_remaining_s", "blend_engagements")
LINK_KEYS = ("round_trip_mean_s", "round_trip_jitter_s", "round_trip_quantile_s", "lead_periods", "plans_sent",
             "plans_received", "plans_lost", "odometry_received", "odometry_missing", "odometry_stale",
             "exhausted_periods", "refused_reports", "reports_received")
_STAT_FIELDS = LINK_KEYS[:-2]
_ZERO = (0.0, 0.0, 0.0)
_THROTTLE_S = 1.0
# a zero's plan of zeros: its basis this far after the newest odometry planned from (a basis of its own, which the
# robot's buffer does not take for a duplicate of that odometry's plan, nor regress for that odometry's)
_STOP_AFTER_S = 1e-5

# a held preview: stamp [ns], positions, velocities, accelerations (each (N + 1, 3): x, y, theta)
_Held = tuple[int, np.ndarray, np.ndarray, np.ndarray]
_Arrays = tuple[np.ndarray, np.ndarray, np.ndarray]
_Report = AppliedReport | Undecodable


def _triple(values: Sequence[float]) -> tuple[float, float, float]:
    a, b, c = values
    return (a, b, c)


def _reference_jump(previous: Sequence[float], dt_s: float, current: Sequence[float], jump_m: float,
                    jump_rad: float) -> str | None:
    """How the reference's first point `current` left the `previous` preview's first point moved by `dt_s`, or None.

    Each point is (x, y, theta, their velocities, their accelerations); a jump is a position more than `jump_m` or a
    heading more than `jump_rad` away from the previous point's Taylor step (`reference.trajectories.shift_preview`,
    here on floats: numpy's per-call cost dominates on one point), e.g. a trajectory node restarted at the origin.
    """
    x, y, theta, vx, vy, w, ax, ay, aw = previous
    half_dt2 = 0.5 * dt_s * dt_s
    dx = current[0] - (x + dt_s * vx + half_dt2 * ax)
    dy = current[1] - (y + dt_s * vy + half_dt2 * ay)
    dtheta = current[2] - (theta + dt_s * w + half_dt2 * aw)
    distance = math.hypot(dx, dy)
    if distance > jump_m or abs(dtheta) > jump_rad:
        return f"reference jumped by {distance:.4g} m, {dtheta:.4g} rad between previews"
    return None


class LoopConfigError(RobotinoError, ValueError):
    """A combination of modes the loop cannot run (e.g. the chain in lockstep)."""


@dataclass(frozen=True)
class LoopSettings:
    """The controller's own parameters (the node's of the same names, `params.specs.LOOP_SPECS`)."""

    odom_timeout_s: float = 0.1
    reference_timeout_s: float = 0.1
    future_tolerance_s: float = 0.05
    quaternion_norm_tolerance: float = QUATERNION_NORM_TOLERANCE
    tilt_tolerance_rad: float = TILT_TOLERANCE_RAD
    reference_jump_m: float = 0.005
    reference_jump_rad: float = 0.02
    blend_acceleration_mps2: float = LINEAR_LIMIT_MPS2
    blend_acceleration_radps2: float = ANGULAR_LIMIT_RADPS2

    @classmethod
    def of(cls, values: Mapping[str, Any]) -> LoopSettings:
        """The settings among `values` (parameter name -> value; others ignored, missing ones at their defaults)."""
        return cls(**{f.name: float(values[f.name]) for f in fields(cls) if f.name in values})

    @property
    def watchdog_period_s(self) -> float:
        """The period of the watchdog's timer: half the shorter timeout."""
        return 0.5 * min(self.odom_timeout_s, self.reference_timeout_s)


class Listeners(Protocol):
    """Whether anyone reads the optional outputs (building them costs: the loop skips them when not)."""

    def diagnostics(self) -> bool: ...

    def path(self) -> bool: ...


class _Everyone:
    def diagnostics(self) -> bool:
        return True

    def path(self) -> bool:
        return True


class _Nobody:
    def diagnostics(self) -> bool:
        return False

    def path(self) -> bool:
        return False


EVERYONE: Listeners = _Everyone()
QUIET: Listeners = _Nobody()  # a replay or an offline run that compares the commands only


class RealtimePairing:
    """Realtime: the freshest preview, stamps checked against the clock, the watchdog stops (module docstring)."""

    name = "realtime"

    def stamp_clock(self, now: Now) -> int | None:
        return now.clock_ns

    def take_odometry(self, loop: ControllerLoop, stamp: int, X: np.ndarray) -> None:
        if not loop.enabled:
            loop._hold(stamp)
            return
        latest, odom, preview = loop.latest_preview, loop._odom_watch_ns, loop._preview_watch_ns
        if latest is None or odom is None or preview is None or odom - preview > loop._reference_timeout_ns:
            return  # stale reference: the watchdog outputs zero
        if loop.chain is not None:
            loop._chain_step(stamp, X, latest)
            return
        loop._control_moved(stamp, X, latest)

    def take_preview(self, loop: ControllerLoop, stamp: int, arrays: _Arrays) -> None:
        return

    def refuse_preview(self, loop: ControllerLoop, stamp: int | None, reason: str, message: str) -> None:
        loop._reject(stamp, "reference_preview", reason, message)

    def resent(self, loop: ControllerLoop, stamp: int) -> None:
        return

    def holds_report(self, report: _Report) -> bool:
        return False

    def start_pose(self, stamp: int, positions: np.ndarray, plans: bool) -> list[float] | None:
        return None

    def waiting_for(self) -> tuple[int, int] | None:
        return None

    def acts_on_stale(self) -> bool:
        return True


class LockstepPairing:
    """Lockstep: each odometry with the preview of its own stamp, in arrival order (module docstring)."""

    name = "lockstep"

    def __init__(self) -> None:
        # stamp [ns] -> (positions, velocities, accelerations), or the refusal of that tick's preview
        self.previews: dict[int, _Arrays | InputRejected] = {}
        # odometries in arrival order, the first waiting for its preview, each with the reports held for it (plans)
        self.waiting: list[tuple[int, np.ndarray, list[_Report]]] = []
        self.pending_since_ns = 0

    def stamp_clock(self, now: Now) -> int | None:
        return None  # stamps are simulated time

    def take_odometry(self, loop: ControllerLoop, stamp: int, X: np.ndarray) -> None:
        waiting = self.waiting
        if not waiting:
            self.pending_since_ns = loop._now.watch_ns  # the odometry's arrival
            waiting.append((stamp, X, []))
        elif all(other != stamp for other, _, _ in waiting):
            waiting.append((stamp, X, []))
        self._drain(loop)

    def take_preview(self, loop: ControllerLoop, stamp: int, arrays: _Arrays) -> None:
        self.previews[stamp] = arrays
        self._drain(loop)

    def refuse_preview(self, loop: ControllerLoop, stamp: int | None, reason: str, message: str) -> None:
        loop.counters.refuse(reason)
        loop._log(Level.WARN, f"refused reference_preview: {message}", "refused_preview")
        if stamp is None:
            return
        self.previews[stamp] = InputRejected(message, reason)
        self._drain(loop)

    def resent(self, loop: ControllerLoop, stamp: int) -> None:
        loop._out.append(Resend(stamp))  # the plant resent a tick: the answers still held may go out (never twice)

    def holds_report(self, report: _Report) -> bool:
        if not self.waiting:
            return False
        self.waiting[-1][2].append(report)
        return True

    def start_pose(self, stamp: int, positions: np.ndarray, plans: bool) -> list[float] | None:
        """Tick t = 0 (over a link, the first tick taken while the preview of t = 0 is known): robot and reference
        start together, as `offline.simulation.simulate` starts.
        """
        if stamp == 0:
            return positions[0].tolist()
        first = self.previews.get(0) if plans else None
        return first[0][0].tolist() if isinstance(first, tuple) else None

    def waiting_for(self) -> tuple[int, int] | None:
        return (self.waiting[0][0], self.pending_since_ns) if self.waiting else None

    def acts_on_stale(self) -> bool:
        return False  # the plant holds the time

    def _drain(self, loop: ControllerLoop) -> None:
        """Step the waiting odometries in arrival order while the preview of the first is there (over a link
        several arrive at one tick, each answered in turn).
        """
        while self.waiting:
            stamp, X, held = self.waiting[0]
            if loop.last_odom_ns is not None and stamp <= loop.last_odom_ns:  # overtaken while it waited
                del self.waiting[0]
                loop._drop(stamp, "odom", "old")
                loop._take_reports(held)  # the reports that came after it (only with plans)
                continue
            arrays = self.previews.get(stamp)
            if arrays is None:
                break
            del self.waiting[0]
            self.pending_since_ns = loop._now.watch_ns
            if isinstance(arrays, InputRejected):
                loop._reject(stamp, "odom", f"preview_{arrays.reason}",
                             f"the preview of this tick was refused: {arrays}")
            else:
                loop._control(stamp, X, *arrays, stamp)
            if held:
                loop._take_reports(held)
            if len(self.previews) > 1:
                for old in [s for s in self.previews if s < stamp]:
                    del self.previews[old]


_Pairing = RealtimePairing | LockstepPairing


class ControllerLoop:
    """The controller's tick protocol (module docstring).

    Parameters
    ----------
    robot, control
        The model and the controller's settings (`params.specs`).
    now
        The time at the start (the watchdog counts from it).
    settings
        The controller's own limits (timeouts, tolerances, reference jump, blend limits).
    lockstep
        `LockstepPairing` if true, else `RealtimePairing` (decided here, once).
    interface
        ``voltages`` (commands in V) or ``cmd_vel`` (base_link twists, `MotionController.next_velocity`).
    plans
        Plans over a link (`control.delay_compensation.DelayCompensatingController`).
    chain
        The driver chain's parameters: the chain controller instead of the MPC (realtime and cmd_vel only).
    enabled
        False: disabled from the start (zero every tick) until `on_enable`.
    odom_frame
        The frame previews must be in (``<frame_prefix>odom``).
    report_window_s
        How far a robot's report may be from the newest odometry stamp.
    listeners
        Whether diagnostics and the predicted path are read (skipped when not).

    Raises
    ------
    LoopConfigError
        For the chain in lockstep or with voltages.
    """

    def __init__(self, robot: RobotinoParams, control: ControlParams, now: Now, settings: LoopSettings = LoopSettings(),
                 *, lockstep: bool = False, interface: str = "voltages", plans: bool = False,
                 chain: ChainParams | None = None, enabled: bool = True, odom_frame: str = "odom",
                 report_window_s: float = REPORT_WINDOW_S, listeners: Listeners = EVERYONE) -> None:
        if chain is not None and (lockstep or interface != "cmd_vel"):
            raise LoopConfigError("chain.active enabled needs mode realtime and command_interface cmd_vel")
        self.robot, self.control, self.interface = robot, control, interface
        self.pairing: _Pairing = LockstepPairing() if lockstep else RealtimePairing()
        self.controller = MotionController(robot, control)
        self.plans = DelayCompensatingController(robot, control, interface) if plans else None
        self.chain = ChainTracker(chain, control.period_s) if chain is not None else None
        # rows of reference after the odometry's stamp a tick needs (a preview has one more: its stamp's)
        self.preview_points = control.horizon if self.plans is None else self.plans.preview_length
        self.period_ns = int(round(control.period_s * 1e9))
        self.enabled = enabled
        self.odom_frame = odom_frame
        self.report_window_s = report_window_s
        self.listeners = listeners
        self.settings = settings
        self.theta = 0.0  # last measured (continuous) yaw
        self.latest_preview: _Held | None = None  # the newest preview (realtime: the one used)
        self._latest_first: tuple[float, ...] = ()  # its first point's 9 values (position, velocity, acceleration)
        self.last_odom_ns: int | None = None  # stamp of the last odometry used (dt, duplicates, order)
        self.counters = InputCounters()
        self.sources = SourcePairing(max(1, int(settings.reference_timeout_s * 1e9)))  # previews: one source
        self.blend = BlendEngagement(control.period_s, self.preview_points)
        self.watchdog_state = "waiting"
        self.newest_stamp_s: float | None = None  # plans: the newest odometry stamp planned from [s]
        self._stopped_after_s: float | None = None  # plans: the newest stamp a plan of zeros was sent after [s]
        self.refused_reports = 0
        self.reports_received = 0  # reports handed on, taken or refused (the replay hands them on so)
        self.last_step: ControlOutput | None = None  # the output of the last MotionController.step (its flags)
        self._start_watch_ns = now.watch_ns
        self._odom_watch_ns: int | None = None  # arrival times of accepted inputs (watch clock)
        self._preview_watch_ns: int | None = None
        self._preview_clock_ns: int | None = None  # the node clock then (statuses: ``preview_clock_ns``)
        self._now = now
        self._out: list[Output] = []
        self._limits()

    # configuration --------------------------------------------------------------------------------------------
    @property
    def lockstep(self) -> bool:
        """Whether the pairing is lockstep."""
        return isinstance(self.pairing, LockstepPairing)

    @property
    def event_keys(self) -> tuple[str, ...]:
        """The keys every status carries (after a tick's own)."""
        return _EVENT_KEYS + (LINK_KEYS if self.plans is not None else ()) + ("clock_ns", "preview_clock_ns")

    def _limits(self) -> None:
        s = self.settings
        self._odom_timeout_ns = int(s.odom_timeout_s * 1e9)
        self._reference_timeout_ns = int(s.reference_timeout_s * 1e9)
        self.sources.lease_ns = max(1, self._reference_timeout_ns)
        self._future_ns = int(s.future_tolerance_s * 1e9)
        self._tolerances = (s.quaternion_norm_tolerance, s.tilt_tolerance_rad)
        self._jump_limits = (s.reference_jump_m, s.reference_jump_rad)
        self._blend_limits = (s.blend_acceleration_mps2, s.blend_acceleration_radps2)

    # inputs -------------------------------------------------------------------------------------------------
    def on_input(self, event: Odometry | PlanarOdometry | Preview | PlanarPreview | AppliedReport | Undecodable,
                 now: Now) -> list[Output]:
        """Any input message (a replay's or an offline loop's single entry): `on_odometry`, `on_preview`,
        `on_report` or `on_undecodable`.
        """
        if isinstance(event, (Odometry, PlanarOdometry)):
            return self.on_odometry(event, now)
        if isinstance(event, (Preview, PlanarPreview)):
            return self.on_preview(event, now)
        if isinstance(event, AppliedReport):
            return self.on_report(event, now)
        return self.on_undecodable(event, now)

    def on_odometry(self, odom: Odometry | PlanarOdometry, now: Now) -> list[Output]:
        """One control tick on an odometry (lockstep: once its preview is there); a planar one's theta as given."""
        self._begin(now)
        stamp = odom.stamp_ns
        problem = stamp_problem(stamp, self.last_odom_ns, self.pairing.stamp_clock(now), self._odom_timeout_ns,
                                self._future_ns)
        if self.chain is not None and problem in ("duplicate", "stale"):
            problem = None  # the chain's stamps are dispatch times: two samples share one, and they are old
        if problem is not None:
            if problem == "duplicate":
                self.pairing.resent(self, stamp)
            if problem in ("duplicate", "old"):
                self._drop(stamp, "odom", problem)
            else:
                self._reject(stamp, "odom", problem, f"stamp {stamp} ns is {problem}")
            return self._out
        try:
            X = (planar_state(odom.pose, odom.twist) if isinstance(odom, PlanarOdometry) else
                 state_of_odometry(odom.values, self.theta, *self._tolerances))
            implausible = self.controller.state_problem(X)
            if implausible is not None:
                raise InputRejected(f"odom {implausible}", "implausible")
        except InputRejected as exc:
            self._reject(stamp, "odom", exc.reason, str(exc))
            return self._out
        self._odom_watch_ns = now.watch_ns
        self.theta = float(X[4])  # a Python float: numpy scalars would slow every unwrap after
        self.pairing.take_odometry(self, stamp, X)
        return self._out

    def on_preview(self, preview: Preview | PlanarPreview, now: Now) -> list[Output]:
        """A reference preview: checked, kept (lockstep: the ticks waiting for it stepped); a planar one's theta as
        given.
        """
        self._begin(now)
        if isinstance(preview, Preview) and preview.source is not None and \
                not self.sources.admit(preview.source, now.watch_ns):
            self.counters.second_source += 1  # the paired source goes on: nothing else is touched
            return self._out
        stamp = preview.stamp_ns
        latest = self.latest_preview
        planar = isinstance(preview, PlanarPreview)
        size = PLANAR_POINT_SIZE if planar else POINT_SIZE
        try:
            if preview.frame != self.odom_frame:  # another robot's odom, or a prefix mismatch
                raise InputRejected(f"reference_preview is in frame '{preview.frame}', not in the controller's "
                                    f"'{self.odom_frame}'", "frame")
            if len(preview.values) < (self.preview_points + 1) * size or len(preview.values) % size:
                raise InputRejected(f"reference_preview has {len(preview.values) / size:g} points, need at least "
                                    f"N + 1 = {self.preview_points + 1}", "size")
            clock = self.pairing.stamp_clock(now)
            if clock is not None:  # lockstep: the trajectory resends previews on purpose, keyed by stamp
                problem = stamp_problem(stamp, None if latest is None else latest[0], clock,
                                        self._reference_timeout_ns, self._future_ns)
                if problem in ("duplicate", "old"):
                    self._drop(stamp, "reference_preview", problem)
                    return self._out
                if problem is not None:
                    raise InputRejected(f"stamp {stamp} ns is {problem}", problem)
            values = preview.values
            arrays = (planar_preview_arrays(values) if planar else
                      preview_of_values(values, self.theta, *self._tolerances))
            if max(max(map(abs, values[0::size])), max(map(abs, values[1::size]))) > MAX_POSITION_M:
                raise InputRejected(f"reference_preview has a position beyond {MAX_POSITION_M:g} m", "implausible")
        except InputRejected as exc:
            self.pairing.refuse_preview(self, stamp, exc.reason, str(exc))
            return self._out
        self._preview_watch_ns, self._preview_clock_ns = now.watch_ns, now.clock_ns
        if latest is None or stamp > latest[0]:
            first = (values[:PLANAR_POINT_SIZE] if planar else
                     (values[0], values[1], float(arrays[0][0, 2]), *values[6:POINT_SIZE]))
            jump = None if latest is None else self._jump_from(latest, stamp, first)
            if jump is not None:
                self.blend.jump_ns = stamp
                self._log(Level.WARN, f"{jump}: bumpless restart", "jump")
            self.latest_preview, self._latest_first = (stamp, *arrays), first
        self.pairing.take_preview(self, stamp, arrays)
        return self._out

    def _jump_from(self, latest: _Held, stamp: int, first: Sequence[float]) -> str | None:
        """`_reference_jump` of the preview stamped `stamp` from the `latest` one's row of the periods elapsed."""
        gap = stamp - latest[0]
        m = whole_periods(gap, self.period_ns, len(latest[1]) - 1)
        previous = self._latest_first if m == 0 else [float(a[m, j]) for a in latest[1:] for j in range(3)]
        return _reference_jump(previous, (gap - m * self.period_ns) * 1e-9, first, *self._jump_limits)

    def on_undecodable(self, bad: Undecodable, now: Now) -> list[Output]:
        """An input that could not be read: refused (a report: counted as the reports are)."""
        self._begin(now)
        if bad.topic == "command_applied":
            return self.on_report(bad, now)
        if bad.topic == "odom":
            self._reject(None, "odom", bad.reason, bad.message)
        else:
            self.pairing.refuse_preview(self, bad.stamp_ns, bad.reason, bad.message)
        return self._out

    def on_report(self, report: AppliedReport | Undecodable, now: Now) -> list[Output]:
        """A robot's ``command_applied`` report (plans), handed to the controller in the order it came (lockstep:
        held while an odometry waits, until it is planned).
        """
        self._begin(now)
        if self.plans is not None and not self.pairing.holds_report(report):
            self._take_reports((report,))
        return self._out

    def on_enable(self, enabled: bool, now: Now) -> list[Output]:
        """``~/enable``: false holds (zero every tick, the controller untouched); true re-engages bumplessly.

        A loop started disabled that has never tracked keeps its pending start engagement.
        """
        self._begin(now)
        if enabled != self.enabled:
            self.enabled = enabled
            if enabled and self.blend.reason != "start":
                self.blend.request("enable")  # u(k-1) = 0 (the robot held), blend from the measured state
            self._out.append(EnabledChanged(enabled))
            self._log(Level.INFO, "enabled: tracking resumes bumplessly" if enabled else
                      "disabled: zero output, holding", "enable", 0.0)
        return self._out

    def on_watchdog(self, now: Now) -> list[Output]:
        """The watchdog's check at `now`: stale odometry or reference gives zero (realtime) and a restart later."""
        self._begin(now)
        watch = now.watch_ns
        odom, preview = self._odom_watch_ns, self._preview_watch_ns
        acts = self.pairing.acts_on_stale()
        if odom is None or preview is None or not acts:
            self._wait_log(watch)
            if odom is None or preview is None:
                return self._out
        if watch - odom > self._odom_timeout_ns:
            state = "stale_odom"
        elif watch - preview > self._reference_timeout_ns:
            state = "stale_reference"
        else:
            state = "ok"
        self.watchdog_state = state
        if state == "ok" or not acts:
            return self._out
        self.blend.request("watchdog")  # data that return restart the tracking bumplessly
        # and are taken on any fresh stamp, also one before the last used (a sim clock reset, a bag replayed in a loop)
        self.last_odom_ns, self.latest_preview = None, None
        self._log(Level.WARN, f"watchdog: {state.replace('_', ' ')}; zero volts", "watchdog")
        self._zero("watchdog")
        self._diagnose(None, Level.WARN, f"watchdog: {state}")
        return self._out

    def on_parameters(self, robot: RobotinoParams, control: ControlParams, settings: LoopSettings, rebuild: bool,
                      now: Now) -> list[Output]:
        """New parameters: the settings taken; `rebuild` (a robot/control parameter changed): a new controller
        (and plans, reports and round trips start over) with a bumpless restart.
        """
        self._begin(now)
        self.settings = settings
        self._limits()
        if rebuild:
            self.robot, self.control = robot, control
            self.controller = MotionController(robot, control)
            if self.plans is not None:
                self.plans = DelayCompensatingController(robot, control, self.interface)
            self.blend.request("parameters")  # the new controller starts from u(k-1) = 0: blend from the state
        return self._out

    def on_stop(self, now: Now) -> list[Output]:
        """Realtime: zero as the driver stops. Lockstep: nothing (the plant pairs every command with its tick)."""
        self._begin(now)
        if self.pairing.acts_on_stale():
            self._zero("stop")
        return self._out

    # the tick ----------------------------------------------------------------------------------------------
    def _control_moved(self, stamp: int, X: np.ndarray, held: _Held) -> None:
        """A step with the preview `held` moved to `stamp` (`reference.trajectories.preview_at`: its rows of the
        periods elapsed, the rest to second order).
        """
        preview_stamp = held[0]
        self._control(stamp, X, *preview_at(stamp, preview_stamp, *held[1:], self.period_ns, self.preview_points + 1),
                      preview_stamp)

    def _control(self, stamp: int, X: np.ndarray, positions: np.ndarray, velocities: np.ndarray,
                 accelerations: np.ndarray, preview_stamp: int) -> None:
        """One step on the odometry of `stamp` and the preview of `preview_stamp` (moved to `stamp`).

        `positions`, `velocities`, `accelerations` are the reference at `stamp` + j Ts, j = 0..N.
        """
        if not self.enabled:
            self._hold(stamp)
            return
        reason = self.blend.due(preview_stamp)
        if reason == "start":
            start = self.pairing.start_pose(stamp, positions, self.plans is not None)
            if start is not None:  # robot and reference start together: no blend
                self.blend.reason = reason = None
                (self.controller if self.plans is None else self.plans).start_at(*start)
        try:
            if reason is not None:
                self._engage(stamp, X, positions[0], velocities[0], accelerations[0], reason)
                dt_s = None  # the controller starts over
            else:  # None: one period exactly, or the first tick
                dt_s = step_interval(stamp, self.last_odom_ns, self.period_ns)
            preview = positions[1:self.preview_points + 1]  # (a longer preview's rows beyond the horizon unused)
            offsets = self.blend.offsets(stamp)
            if offsets is not None:
                preview = preview + offsets
            if self.plans is not None:
                self._plan(stamp, X, preview, X[0::2] - positions[0], preview_stamp)
                return
            out = self.controller.step(X, preview, dt_s)
        except (ControllerInputError, BlendError) as exc:
            self._reject(stamp, "input", "controller", str(exc))
            return
        except Exception as exc:  # a bug must not leave the drives at the last voltages: zero, and start over
            self._log(Level.ERROR, f"control step failed: {exc!r}\n{traceback.format_exc()}", "internal_error")
            self.blend.request("error")
            self._reject(stamp, "input", "internal_error", repr(exc))
            return
        self.last_odom_ns, self.last_step = stamp, out
        command = self.controller.next_velocity() if self.interface == "cmd_vel" else out.voltages
        self._out.append(Command(stamp, _triple(command)))
        if self.listeners.path():
            poses = self.controller.predicted_outputs()
            stamps = tuple(stamp + j * self.period_ns for j in range(1, len(poses) + 1))
            self._out.append(PredictedPath(stamp, stamps, poses))
        if not self.listeners.diagnostics():
            return
        error = X[0::2] - positions[0]
        flags = (out.saturated, out.infeasible)
        tracking = [f"{e:.9g}" for e in error.tolist()] + [
            f"{out.compute_time_s * 1e3:.4f}", str(flags[0]).lower(), str(flags[1]).lower(), str(preview_stamp),
            f"{self.control.period_s if dt_s is None else dt_s:.9g}"]
        self._diagnose(stamp, Level.WARN if any(flags) else Level.OK, "tracking", TRACKING_KEYS, tracking)

    def _plan(self, stamp: int, X: np.ndarray, preview: np.ndarray, error: np.ndarray, preview_stamp: int) -> None:
        """Plans: the plan of this odometry, its first entry as the plain command (none for an odometry not newer
        than one taken: it came reordered or twice over the link).
        """
        assert self.plans is not None
        begin = time.perf_counter()  # for the diagnostic's compute time only
        self.newest_stamp_s = stamp * 1e-9
        plan = self.plans.plan(self.newest_stamp_s, X, preview)
        if plan is None:
            self._drop(stamp, "odom", "old")
            return
        self.last_odom_ns = stamp
        self._out.append(PlanOut(stamp, plan))
        self._out.append(Command(stamp, _triple(plan.entries[0])))
        if self.listeners.diagnostics():
            self._diagnose(stamp, Level.OK, "tracking", TRACKING_KEYS, [f"{e:.9g}" for e in error.tolist()] + [
                f"{(time.perf_counter() - begin) * 1e3:.4f}", "false", "false", str(preview_stamp),
                f"{self.control.period_s:.9g}"])

    def _chain_step(self, stamp: int, X: np.ndarray, held: _Held) -> None:
        """The chain controller's step at the clock handed in: its twist, or a refusal."""
        assert self.chain is not None
        try:
            twist = self.chain.step(stamp, self._now.clock_ns, X, held)
        except ChainControllerError as exc:
            self._reject(stamp, "input", "controller", str(exc))
            return
        self.last_odom_ns = stamp
        self._out.append(Command(stamp, _triple(twist)))
        self._diagnose(stamp, Level.OK, "chain", ("preview_stamp_ns",), [str(held[0])])

    def _engage(self, stamp: int, X: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                acceleration: np.ndarray, reason: str) -> None:
        """Bumpless (re)start: reset the controller and blend the reference in from the measured state."""
        self.controller.reset()
        if self.plans is not None:
            self.plans.reset()
        blend = self.blend.engage(stamp, X, position, velocity, acceleration, *self._blend_limits)
        if self.blend.blend is not None:
            limited = " (limit raised: the reference's own acceleration needs more)" if blend.limited else ""
            self._log(Level.INFO,
                      f"bumpless restart ({reason}) at stamp {stamp} ns: offset {np.round(blend.dp, 6).tolist()}, "
                      f"rate {np.round(blend.dv, 6).tolist()}, blended in over {blend.duration_s:.3f} s{limited}",
                      "restart", 0.0)

    def _hold(self, stamp: int) -> None:
        """Disabled: zero for the odometry of `stamp` and the status ``disabled`` (through the chain, the zero
        noted in its controller's command model: the firmware gets it as any other command; with plans, a plan of
        zeros too, `DelayCompensatingController.stop_plan`, which replaces the plans the robot holds).
        """
        self.last_odom_ns = stamp
        if self.chain is not None:
            self.chain.note_zero(self._now.clock_ns)
        if self.plans is not None:
            self.newest_stamp_s = self._stopped_after_s = stamp * 1e-9  # (the robot's reports lie near it)
            self._out.append(PlanOut(stamp, self.plans.stop_plan(self.newest_stamp_s)))
        self._out.append(Command(stamp, _ZERO))
        self._diagnose(stamp, Level.OK, "disabled")

    # plans' reports ------------------------------------------------------------------------------------------
    def _take_reports(self, reports: tuple[_Report, ...] | list[_Report]) -> None:
        """Hand reports to the plan controller in the order they came; refused: counted, logged."""
        assert self.plans is not None or not reports
        for report in reports:
            self.reports_received += 1
            if isinstance(report, Undecodable):
                problem: tuple[str, str] | None = (report.reason, report.message)
            else:
                problem = report_problem(report.time_s, self.newest_stamp_s, self.report_window_s)
            if problem is not None:
                self.refused_reports += 1
                self._log(Level.WARN, f"refused command_applied ({problem[0]}: {problem[1]}); "
                          f"{self.refused_reports} refused so far", "refused_report")
                continue
            assert isinstance(report, AppliedReport) and self.plans is not None
            if report.values is None:
                assert report.basis_s is not None
                self.plans.report_receipt(report.basis_s, report.time_s, report.taken)
            else:
                self.plans.report_applied(report.time_s, report.basis_s, max(report.entry_index, 0))

    # what leaves ---------------------------------------------------------------------------------------------
    def _begin(self, now: Now) -> None:
        self._now = now
        self._out = []

    def _log(self, level: Level, text: str, key: str, throttle_s: float = _THROTTLE_S) -> None:
        self._out.append(Log(level, text, key, throttle_s))

    def _zero(self, reason: str) -> None:
        """Zero volts (zero twist) outside the answers; through the chain noted in its command model; with plans
        also a plan of zeros (`DelayCompensatingController.stop_plan`) just after the newest odometry planned from,
        once per such odometry: the plans the robot holds would otherwise run on.
        """
        if self.chain is not None:
            self.chain.note_zero(self._now.clock_ns)
        self._out.append(Zero(reason))
        if self.plans is not None and self.newest_stamp_s is not None and self._stopped_after_s != self.newest_stamp_s:
            self._stopped_after_s = self.newest_stamp_s
            basis_s = self.newest_stamp_s + _STOP_AFTER_S
            self._out.append(PlanOut(round(basis_s * 1e9), self.plans.stop_plan(basis_s)))

    def _reject(self, stamp: int | None, what: str, reason: str, message: str) -> None:
        """A refused input: counted, logged, zero, an ERROR status naming the reason."""
        self.counters.refuse(reason)
        self._log(Level.WARN, f"refused {what}: {message}; zero volts", "refused")
        self._zero(reason)
        self._diagnose(stamp, Level.ERROR, f"refused {what} ({reason}): {message}")

    def _drop(self, stamp: int, what: str, reason: str) -> None:
        """A dropped input (duplicate or older stamp than the last used): counted, logged, a WARN status."""
        self.counters.drop(reason)
        self._log(Level.WARN, f"dropped {what} of stamp {stamp} ns: {reason}", "dropped")
        self._diagnose(stamp, Level.WARN, f"dropped {what} ({reason})")

    def _diagnose(self, stamp: int | None, level: Level, message: str, keys: tuple[str, ...] = (),
                  values: list[str] | None = None) -> None:
        """A status (if anyone reads them): `keys`/`values` of the tick, then the event values; `stamp` None: the
        clock handed in.
        """
        if not self.listeners.diagnostics():
            return
        stamp = self._now.clock_ns if stamp is None else stamp
        self._out.append(Diagnostic(stamp, level, message, keys + self.event_keys,
                                    tuple((values or []) + self._event_values(stamp))))

    def _event_values(self, stamp: int) -> list[str]:
        """The values of `event_keys` at `stamp` [ns]."""
        values = [self.watchdog_state, *self.counters.values(), f"{self.blend.remaining_s(stamp):.4f}",
                  str(self.blend.engagements)]
        if self.plans is not None:
            stats = self.plans.statistics()
            for name in _STAT_FIELDS:
                value = getattr(stats, name)
                values.append("nan" if isinstance(value, float) and np.isnan(value) else
                              f"{value:.6f}" if isinstance(value, float) else str(value))
            values += [str(self.refused_reports), str(self.reports_received)]
        values += [str(self._now.clock_ns), "" if self._preview_clock_ns is None else str(self._preview_clock_ns)]
        return values

    def _wait_log(self, watch_ns: int) -> None:
        """Say what the controller waits for when it has heard nothing for a timeout."""
        pending = self.pairing.waiting_for()
        start, odom = self._start_watch_ns, self._odom_watch_ns
        if pending is not None and watch_ns - pending[1] > self._reference_timeout_ns:
            self._out.append(Waiting("preview_of_stamp", (watch_ns - pending[1]) * 1e-9, pending[0]))
        elif watch_ns - (start if odom is None else odom) > self._odom_timeout_ns:
            self._out.append(Waiting("odometry", (watch_ns - (start if odom is None else odom)) * 1e-9,
                                     since_start=odom is None))
        elif self._preview_watch_ns is None and watch_ns - start > self._reference_timeout_ns:
            self._out.append(Waiting("preview", (watch_ns - start) * 1e-9))
