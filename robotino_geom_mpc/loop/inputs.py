"""The checks of the controller loop's inputs: plain float operations on values already decoded (no rclpy).

The adapters (`nodes.controller_node`, the replay) read a message's fields; these functions check and convert
them: a stamp's problem against the last used one and a clock (`stamp_problem`), a yaw quaternion
(`check_yaw_quaternion`), the body state of an odometry (`state_of_odometry`, eq. 2) and the arrays of a
preview (`preview_of_values`); an in-process robot's planar odometry and preview (the yaw without a quaternion:
`planar_state`, `planar_preview_arrays`) are only checked for finiteness. A refused input raises
`InputRejected`, whose `reason` is the short key the loop counts (`InputCounters`) and reports; `report_problem`
says when a robot's report is too far from the newest odometry.
"""

from __future__ import annotations

import math

import numpy as np

from robotino_geom_mpc.control.motion_controller import state_from_odometry
from robotino_geom_mpc.errors import RobotinoError

__all__ = ["InputCounters", "InputRejected", "PLANAR_POINT_SIZE", "POINT_SIZE", "QUATERNION_NORM_TOLERANCE",
           "REPORT_WINDOW_S", "TILT_TOLERANCE_RAD", "check_yaw_quaternion", "planar_preview_arrays", "planar_state",
           "preview_of_values", "report_problem", "stamp_problem", "state_of_odometry", "time_ns", "unwrap_near",
           "yaw_of"]

POINT_SIZE = 12  # per preview point: x, y, the yaw quaternion, velocity and acceleration (x, y, theta)
PLANAR_POINT_SIZE = 9  # per planar preview point (in-process): x, y, theta, velocity and acceleration (x, y, theta)
# defaults of the controller's quaternion checks (its parameters quaternion_norm_tolerance, tilt_tolerance_rad)
QUATERNION_NORM_TOLERANCE = 1e-3  # relative: | |q| - 1 | above this is refused
TILT_TOLERANCE_RAD = 0.05  # roll/pitch: the body z axis tilted more than this from the odom z axis is refused


class InputRejected(RobotinoError, ValueError):
    """An odometry or preview message that is refused: non-finite values, wrong size, a quaternion that is not a yaw.

    Attributes
    ----------
    reason
        Short key of the refusal (``non_finite``, ``size``, ``quaternion_norm``, ``quaternion_tilt``, ...).
    """

    def __init__(self, message: str, reason: str = "invalid") -> None:
        super().__init__(message)
        self.reason = reason


def check_yaw_quaternion(qx: float, qy: float, qz: float, qw: float, what: str,
                         norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                         tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> None:
    """Refuse a quaternion that is not a unit rotation about z (the planar robot's heading, REP-103).

    The norm must be within `norm_tolerance` of 1 (relative): the all-zero
    quaternion is no rotation, and (0, 0, 0.5, 0.5) is not pi/4 about z but no
    rotation at all. The rotation may tilt the body's z axis by at most
    `tilt_tolerance_rad` (roll/pitch): the tilt t has cos t = 1 - 2 (q_x^2 + q_y^2) / |q|^2,
    so the test is (q_x^2 + q_y^2) / |q|^2 <= sin^2(t_max / 2).

    Raises
    ------
    InputRejected
        With reason ``quaternion_norm`` or ``quaternion_tilt``; `what` names the input in the message.
    """
    xy = qx * qx + qy * qy
    norm2 = xy + qz * qz + qw * qw
    if not abs(math.sqrt(norm2) - 1.0) <= norm_tolerance:
        raise InputRejected(f"{what} quaternion ({qx:g}, {qy:g}, {qz:g}, {qw:g}) has norm {math.sqrt(norm2):.6g}, "
                            f"not 1 within {norm_tolerance:g}", "quaternion_norm")
    half = math.sin(0.5 * tilt_tolerance_rad)
    if xy > half * half * norm2:
        tilt = math.acos(max(-1.0, 1.0 - 2.0 * xy / norm2))
        raise InputRejected(f"{what} quaternion ({qx:g}, {qy:g}, {qz:g}, {qw:g}) tilts the robot by {tilt:.4g} rad "
                            f"(roll/pitch), more than {tilt_tolerance_rad:g}", "quaternion_tilt")


def stamp_problem(stamp_ns: int, last_ns: int | None, now_ns: int | None, timeout_ns: int,
                  future_ns: int) -> str | None:
    """What is wrong with an input's stamp, as a reason key, or None.

    Parameters
    ----------
    stamp_ns
        The input's header stamp.
    last_ns
        The stamp of the last input of this kind that was used (None: none yet).
    now_ns
        The receiver's clock (None: not comparable, e.g. lockstep, where stamps are simulated time).
    timeout_ns, future_ns
        How old, and how far ahead of `now_ns`, a stamp may be.

    Returns
    -------
    ``"future"`` (ahead of now by more than `future_ns`) or ``"stale"`` (older than `timeout_ns`):
    the input is refused; ``"duplicate"`` (the stamp of the last used one) or ``"old"`` (older than it,
    e.g. a message that arrived late, or a clock that went back): the input is dropped; None: fine.
    """
    if now_ns is not None:
        if stamp_ns - now_ns > future_ns:
            return "future"
        if now_ns - stamp_ns > timeout_ns:
            return "stale"
    if last_ns is not None and stamp_ns <= last_ns:
        return "duplicate" if stamp_ns == last_ns else "old"
    return None


def time_ns(sec: int, nanosec: int) -> int:
    """An input's header stamp (sec, nanosec) as integer nanoseconds.

    Raises
    ------
    InputRejected
        With reason ``stamp`` for a time ROS does not have: sec < 0 or nanosec outside [0, 1e9)
        (``sec = 2^31 - 1, nanosec = 2^32 - 1`` would otherwise overflow the stamps of the answers).
    """
    if sec < 0 or not 0 <= nanosec < 1_000_000_000:
        raise InputRejected(f"stamp ({sec} s, {nanosec} ns) is no time: sec >= 0 and 0 <= nanosec < 1e9", "stamp")
    return sec * 1_000_000_000 + nanosec


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rad, in (-pi, pi]) of the quaternion (x, y, z, w) (ZYX convention)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def unwrap_near(angle: float, reference: float) -> float:
    """`angle + 2 pi k` closest to `reference` (continuous yaw from a wrapped one)."""
    difference = reference - angle
    if -math.pi < difference < math.pi:  # k = 0 (the common case): the same float, without the division and round
        return angle + 0.0
    return angle + 2.0 * math.pi * round(difference / (2.0 * math.pi))


def state_of_odometry(values: tuple, previous_theta: float, norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                      tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> np.ndarray:
    """Body state X = (x, x', y, y', theta, theta') (eq. 2) of `odometry_values` (without the stamp).

    theta is unwrapped next to `previous_theta`; the base_link twist is
    rotated into ``odom`` by the measured heading (`control.motion_controller.state_from_odometry`).

    Raises
    ------
    InputRejected
        If any value is not finite (reason ``non_finite``), or the orientation is not a yaw
        (`check_yaw_quaternion` with the tolerances).
    """
    x, y, qx, qy, qz, qw, vx, vy, omega = values
    if not math.isfinite(sum(values)):
        raise InputRejected("odom contains non-finite values", "non_finite")
    check_yaw_quaternion(qx, qy, qz, qw, "odom", norm_tolerance, tilt_tolerance_rad)
    theta = unwrap_near(yaw_of(qx, qy, qz, qw), previous_theta)
    return np.array(state_from_odometry((x, y, theta), (vx, vy, omega)))


def preview_of_values(values: tuple, theta_near: float, norm_tolerance: float = QUATERNION_NORM_TOLERANCE,
                      tilt_tolerance_rad: float = TILT_TOLERANCE_RAD) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (x, y, theta), velocities and accelerations of `preview_point_values`, each (N + 1, 3).

    Theta is unwrapped from `theta_near`.

    Raises
    ------
    InputRejected
        If a value is not finite (reason ``non_finite``) or a point's rotation is not a yaw
        (`check_yaw_quaternion` with the tolerances, on every point).
    """
    if not math.isfinite(sum(values)):
        raise InputRejected("reference_preview contains non-finite values", "non_finite")
    half = math.sin(0.5 * tilt_tolerance_rad)
    tilt_bound = half * half
    rows = list(values)  # each point's yaw quaternion becomes its unwrapped theta (x, y, theta at 0..2)
    theta = theta_near
    # Python floats per point: numpy's per-call cost on a handful of points outweighs the arithmetic.
    for start in range(2, len(rows) - POINT_SIZE + 3, POINT_SIZE):
        qx, qy, qz, qw = rows[start:start + 4]
        xy = qx * qx + qy * qy
        norm2 = xy + qz * qz + qw * qw
        if not abs(math.sqrt(norm2) - 1.0) <= norm_tolerance or xy > tilt_bound * norm2:
            check_yaw_quaternion(qx, qy, qz, qw, f"reference_preview point {start // POINT_SIZE}", norm_tolerance,
                                 tilt_tolerance_rad)  # names the refusal
        theta = unwrap_near(yaw_of(qx, qy, qz, qw), theta)
        rows[start] = theta
    points = np.array(rows, dtype=float).reshape(-1, POINT_SIZE)
    return points[:, :3], points[:, 6:9], points[:, 9:12]


def planar_state(pose: tuple[float, float, float], twist: tuple[float, float, float]) -> np.ndarray:
    """Body state X (eq. 2) of a `loop.events.PlanarOdometry`'s pose (theta continuous) and body twist.

    Raises
    ------
    InputRejected
        If any value is not finite (reason ``non_finite``).
    """
    if not math.isfinite(sum(pose) + sum(twist)):
        raise InputRejected("odom contains non-finite values", "non_finite")
    return np.array(state_from_odometry(pose, twist))


def planar_preview_arrays(values: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (x, y, theta), velocities and accelerations of a `loop.events.PlanarPreview`'s values, each (N + 1, 3).

    Raises
    ------
    InputRejected
        If a value is not finite (reason ``non_finite``).
    """
    if not math.isfinite(sum(values)):
        raise InputRejected("reference_preview contains non-finite values", "non_finite")
    points = np.array(values, dtype=float).reshape(-1, PLANAR_POINT_SIZE)
    return points[:, :3], points[:, 3:6], points[:, 6:9]


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
        self.second_source = 0  # previews of a second source refused (no zero: the paired source goes on)

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
        return [str(self.rejected), self.last_refusal, str(self.dropped_duplicate), str(self.dropped_old),
                str(self.second_source)]

    KEYS = ("rejected", "last_refusal", "dropped_duplicate", "dropped_old", "refused_second_source")


REPORT_WINDOW_S = 2.0
"""A ``command_applied`` report further than this from the newest odometry stamp is refused [s]."""


def report_problem(time_s: float, newest_s: float | None, window_s: float = REPORT_WINDOW_S
                   ) -> tuple[str, str] | None:
    """(reason ``future`` or ``past``, message) for a report time more than `window_s` from the newest odometry
    stamp `newest_s` (a stamp far off; None: no odometry yet, any time), else None.
    """
    if newest_s is not None and abs(time_s - newest_s) > window_s:
        which = "future" if time_s > newest_s else "past"
        return which, (f"time {time_s:.6f} s is {abs(time_s - newest_s):.3f} s in the {which} of the newest "
                       f"odometry ({newest_s:.6f} s)")
    return None
