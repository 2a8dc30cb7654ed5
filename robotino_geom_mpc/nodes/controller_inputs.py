"""The controller node's input bookkeeping: its own parameters, refusal and drop counters, reference jumps, the blend.

Plain Python (no rclpy), so each piece is a few float operations on values
the node has already read; `controller_node` wires them to the topics.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from robotino_geom_mpc.core.blend import ReferenceBlend
from robotino_geom_mpc.core.errors import RobotinoError
from robotino_geom_mpc.core.mpc import check_closed_loop
from robotino_geom_mpc.core.params import ParamError, ParamSpec, params_from_values
from robotino_geom_mpc.core.trajectory import shift_preview
from robotino_geom_mpc.ros.decode import QUATERNION_NORM_TOLERANCE, TILT_TOLERANCE_RAD

__all__ = ["CONTROLLER_DEFAULTS", "CONTROLLER_SPECS", "FIXED_WHILE_RUNNING", "BlendEngagement", "InputCounters",
           "closed_loop_problem", "reference_jump"]

CONTROLLER_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("mode", str, "realtime: freshest preview, watchdog outputs zero volts; lockstep: preview of the same stamp",
              choices=("realtime", "lockstep")),
    ParamSpec("odom_timeout_s", float, "Odometry older than this (arrival, and stamp against the node clock in "
              "realtime) is stale: zero volts", "s", 0.0, 60.0, True),
    ParamSpec("reference_timeout_s", float, "Reference preview older than this (arrival, and stamp against the node "
              "clock in realtime) is stale: zero volts", "s", 0.0, 60.0, True),
    ParamSpec("future_tolerance_s", float, "Realtime: an input stamped further ahead of the node clock is refused",
              "s", 0.0, 60.0, False),
    ParamSpec("quaternion_norm_tolerance", float, "An odometry or preview quaternion whose norm differs from 1 by more "
              "(relative) is refused", "", 0.0, 0.5, True),
    ParamSpec("tilt_tolerance_rad", float, "An odometry or preview orientation with more roll/pitch (tilt of the z "
              "axis) is refused", "rad", 0.0, 0.5 * math.pi, True),
    ParamSpec("reference_jump_m", float, "A preview whose reference position moved by more than this from the "
              "previous preview (moved to its stamp) restarts the tracking bumplessly", "m", 0.0, 1e3, True),
    ParamSpec("reference_jump_rad", float, "The same for the reference heading", "rad", 0.0, 1e3, True),
    ParamSpec("blend_acceleration_mps2", float, "Bound on |(x'', y'')| of the bumpless-restart offset (its duration "
              "is the shortest that meets it)", "m/s^2", 0.0, 100.0, True),
    ParamSpec("blend_acceleration_radps2", float, "Bound on |theta''| of the bumpless-restart offset", "rad/s^2", 0.0,
              1000.0, True),
)
CONTROLLER_DEFAULTS: dict[str, Any] = {
    "mode": "realtime", "odom_timeout_s": 0.1, "reference_timeout_s": 0.1, "future_tolerance_s": 0.05,
    "quaternion_norm_tolerance": QUATERNION_NORM_TOLERANCE, "tilt_tolerance_rad": TILT_TOLERANCE_RAD,
    "reference_jump_m": 0.005, "reference_jump_rad": 0.02,
    "blend_acceleration_mps2": 0.3, "blend_acceleration_radps2": 1.0,
}
# the mode, and what must agree with the trajectory node (the preview's layout)
FIXED_WHILE_RUNNING = ("mode", "control.period_s", "control.horizon")


def closed_loop_problem(values: dict[str, Any]) -> str | None:
    """Why the candidate parameter values cannot run (an unstable nominal closed loop, ...), or None."""
    try:
        check_closed_loop(*params_from_values(values, "parameters of the controller"))
    except (RobotinoError, ParamError) as exc:
        return str(exc)
    return None


def reference_jump(previous: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None, stamp_ns: int,
                   position: np.ndarray, jump_m: float, jump_rad: float) -> str | None:
    """How the reference at `stamp_ns` (`position`, x y theta) left the `previous` preview moved there, or None.

    `previous` is (stamp, positions, velocities, accelerations) of the last preview; a jump is a
    position more than `jump_m` or a heading more than `jump_rad` away from its Taylor step
    (`core.trajectory.shift_preview`), e.g. a trajectory node restarted at the origin.
    """
    if previous is None:
        return None
    stamp, positions, velocities, accelerations = previous
    expected = shift_preview(positions[0], velocities[0], accelerations[0], (stamp_ns - stamp) * 1e-9)
    dx, dy, dtheta = (position - expected).tolist()
    distance = math.hypot(dx, dy)
    if distance > jump_m or abs(dtheta) > jump_rad:
        return f"reference jumped by {distance:.4g} m, {dtheta:.4g} rad between previews"
    return None


class InputCounters:
    """Refused and dropped inputs, counted since the start, with the reason of the last refusal.

    A refused input (bad stamp, quaternion, value or size) gets zero volts; a dropped one (a duplicate
    or older stamp than the last used) is only counted: a newer input was used already.
    """

    def __init__(self) -> None:
        self.rejected = 0
        self.last_refusal = "none"
        self.dropped_duplicate = 0
        self.dropped_old = 0

    def refuse(self, reason: str) -> None:
        """Count a refusal with its reason key."""
        self.rejected += 1
        self.last_refusal = reason

    def drop(self, reason: str) -> None:
        """Count a drop: `reason` is ``duplicate`` or ``old``."""
        if reason == "duplicate":
            self.dropped_duplicate += 1
        else:
            self.dropped_old += 1

    def values(self) -> list[str]:
        """The diagnostic values of `KEYS`."""
        return [str(self.rejected), self.last_refusal, str(self.dropped_duplicate), str(self.dropped_old)]

    KEYS = ("rejected", "last_refusal", "dropped_duplicate", "dropped_old")


class BlendEngagement:
    """The node's bumpless (re)start: when to engage a `core.blend.ReferenceBlend`, and the offsets of each tick.

    Parameters
    ----------
    period_s, horizon
        Ts and N (the preview points 1..N lie at t_k + j Ts).
    """

    def __init__(self, period_s: float, horizon: int) -> None:
        self.period_s = period_s
        self.preview_times = period_s * np.arange(1, horizon + 1)
        self.reason: str | None = "start"  # why the next tick engages (None: it does not)
        self.jump_ns: int | None = None  # stamp of a preview whose reference jumped (engage at the tick using it)
        self.blend: ReferenceBlend | None = None
        self.t0_ns = 0
        self.engagements = 0

    def request(self, reason: str) -> None:
        """Engage at the next tick."""
        self.reason = reason
        self.blend = None

    def due(self, preview_stamp_ns: int) -> str | None:
        """The reason to engage at a tick using the preview of `preview_stamp_ns`, or None."""
        if self.jump_ns is not None and preview_stamp_ns >= self.jump_ns:
            self.jump_ns = None
            return self.reason or "reference_jump"
        return self.reason

    def engage(self, stamp_ns: int, X: np.ndarray, position: np.ndarray, velocity: np.ndarray,
               acceleration: np.ndarray, linear_limit: float, angular_limit: float) -> ReferenceBlend:
        """Engage the blend from the measured state X (eq. 2) to the reference (position, velocity, acceleration).

        dp = measured pose - reference, dv = measured velocity - reference velocity, da = - reference
        acceleration (the controller is reset with it: u(k-1) = 0). An all-zero offset (the robot exactly
        on a reference at rest, as in the nominal start) leaves no blend.
        """
        dp = X[0::2] - position
        dv = X[1::2] - velocity
        blend = ReferenceBlend.engage(0.0, dp, dv, -acceleration, linear_limit, angular_limit, self.period_s)
        self.reason, self.t0_ns, self.engagements = None, stamp_ns, self.engagements + 1
        self.blend = None if not (dp.any() or dv.any() or acceleration.any()) else blend
        return blend

    def offsets(self, stamp_ns: int) -> np.ndarray | None:
        """The offsets o(t_k + j Ts), j = 1..N, of the tick `stamp_ns` (shape (N, 3)), or None (no blend)."""
        if self.blend is None:
            return None
        t = (stamp_ns - self.t0_ns) * 1e-9
        if t >= self.blend.duration_s:
            self.blend = None
            return None
        return self.blend.offset(t + self.preview_times)

    def remaining_s(self, stamp_ns: int) -> float:
        """Time left of the blend at `stamp_ns` [s]."""
        return 0.0 if self.blend is None else self.blend.remaining_s((stamp_ns - self.t0_ns) * 1e-9)
