"""Nav2's FollowPath over a `GoalReference`: a planner's path in any frame, replans, cancel, goal and progress checks.

What ``controller_server`` does for Nav2 (the ``follow_path`` action of nav2_msgs/action/FollowPath), with the
paper's controller behind it: `PathFollower` turns each goal's path into the C^3 reference the MPCs track and says,
each control period, whether the goal has ended and how. Plain Python over `reference.goals.GoalReference`; the
action server (`nodes.follow_path_server`) only decodes goals and answers.

A goal
------
``path`` (nav_msgs/Path: poses a few cm apart, no timestamps, in a frame with a transform to ``odom``) is
transformed into ``odom`` with the newest transform odom <- path frame (`Lookup`), its headings unwrapped pose by
pose from the reference's (by default only the last pose's heading counts: ``use_path_orientations``), the poses
behind the reference pruned (below), and followed from the reference's full state (`GoalReference.follow`: C^3
from the current reference state, within the velocity, acceleration, jerk and rim-speed limits). A goal during
another replaces its path the same way (bt_navigator replans about once a second), so a replan makes no step in
the reference and none in the commands.

Pruning: a planner's path starts at the robot; the poses up to the one nearest the reference (searched from the
last one reached, within `PRUNE_WINDOW_M` of path length, so a path that loops back is not cut short) are dropped,
the path is followed from the next.

The same course: a new path whose poses ahead all lie within ``same_course_tolerance`` of the course the reference
still has to run, and its end within it of the reference's end (the heading counted as the wheels roll it), is
bt_navigator's replan of an unchanged route, its end moved a little: it is not retimed. The rest of the reference
is moved by the difference of the ends, eased in over the time it has left (`GoalReference.shift`), so the robot
goes on at its speed and ends at the new end. Any other path is timed anew from the reference's state
(`GoalReference.follow`: its time law starts from rest, the reference's own velocity carried over and braked by the
blend of `reference.path_timing`).

map -> odom
-----------
Every period the transform is looked up again; when it moved by more than `CORRECTION_M` or `CORRECTION_RAD`
(a localization correction), the poses not yet reached are transformed with the new one and taken as a new path
(a small correction is the same course: the reference's end moves): the robot goes to where the path is now, with
no step. Between corrections the path is fixed in
``odom``, so odometry drift is not followed (that is what the corrections are for).

Ending (Nav2's codes, `Nav2Error`)
---------------------------------
- SUCCEEDED: the reference has come to rest at the path's end (in ``odom``, by the newest transform) and the
  robot is within ``xy_goal_tolerance`` and ``yaw_goal_tolerance`` of it (Nav2's SimpleGoalChecker, with the
  reference's end standing in for its velocity check: the robot is not stopped by the success, it is already
  there).
- FAILED_TO_MAKE_PROGRESS: the robot has not moved ``required_movement_radius`` from where it was
  ``movement_time_allowance`` ago and has not succeeded (Nav2's SimpleProgressChecker).
- INVALID_PATH (an empty path, a non-finite pose or a quaternion that is not a rotation about z), TF_ERROR (no
  transform from the path's frame to ``odom``), NO_VALID_CONTROL (no timing of the path within the limits),
  INVALID_CONTROLLER (a controller, goal checker or progress checker id that is not this controller's).
- CANCELED: a cancel brakes the reference to rest within the limits (`GoalReference.stop`) and ends when it is
  at rest.
Every abort during a goal brakes the reference the same way; a refused goal leaves a running one's reference to
the caller (`PathFollower.refuse`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.reference.frames import FrameError, Rigid, transform_planar
from robotino_geom_mpc.reference.goal_motion import GoalError, MotionLimits
from robotino_geom_mpc.reference.goals import GoalReference

__all__ = ["FEEDBACK_PERIOD_S", "FollowPathError", "FollowPathSettings", "Lookup", "Nav2Error", "Outcome",
           "PathFollower"]

PRUNE_WINDOW_M = 1.0  # path length ahead of the last pose reached in which the nearest pose is searched
CORRECTION_M = 5e-4  # a transform that moved more than this (or `CORRECTION_RAD`) is a correction: replan
CORRECTION_RAD = 1e-3
FEEDBACK_PERIOD_S = 0.05  # feedback at 20 Hz of reference time, Nav2's default controller_frequency

Lookup = Callable[[str, str], Rigid]
"""lookup(target, source) -> T_target_source, the newest (tf2's lookupTransform(target, source) at time 0, e.g.
`reference.frames.TransformTree.lookup`); raises `reference.frames.FrameError`."""


class Nav2Error(IntEnum):
    """The error codes of nav2_msgs/action/FollowPath's result (jazzy)."""

    NONE = 0
    UNKNOWN = 100
    INVALID_CONTROLLER = 101
    TF_ERROR = 102
    INVALID_PATH = 103
    PATIENCE_EXCEEDED = 104
    FAILED_TO_MAKE_PROGRESS = 105
    NO_VALID_CONTROL = 106
    CONTROLLER_TIMED_OUT = 107


class FollowPathError(RobotinoError, ValueError):
    """A goal that cannot be followed, with the Nav2 error code that says why."""

    def __init__(self, code: Nav2Error, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class FollowPathSettings:
    """The server's ids and checks (parameters ``follow_path.*`` of the trajectory node).

    Attributes
    ----------
    controller_id, goal_checker_id, progress_checker_id
        The one id of each this server answers to (a goal's empty id means it too).
    xy_goal_tolerance, yaw_goal_tolerance
        SimpleGoalChecker's: the robot within this distance [m] and heading difference [rad] of the path's end.
    same_course_tolerance
        A new path within this distance [m] of the reference's course moves its end instead of retiming it (0: every
        new path is retimed).
    use_path_orientations
        False (as MPPI's PathAlignCritic by default): the heading turns from the robot's to the last pose's in
        proportion to the distance along the path (NavFn leaves every pose but the last at yaw 0); True: through each
        pose's heading (Smac, a smoother).
    required_movement_radius, movement_time_allowance
        SimpleProgressChecker's: the robot moves this far [m] within this long [s], or the goal fails.
    """

    controller_id: str = "FollowPath"
    goal_checker_id: str = "goal_checker"
    progress_checker_id: str = "progress_checker"
    xy_goal_tolerance: float = 0.02
    yaw_goal_tolerance: float = 0.035
    required_movement_radius: float = 0.5
    movement_time_allowance: float = 10.0
    same_course_tolerance: float = 0.1
    use_path_orientations: bool = False

    def __post_init__(self) -> None:
        for name in ("xy_goal_tolerance", "yaw_goal_tolerance", "required_movement_radius",
                     "movement_time_allowance"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise FollowPathError(Nav2Error.UNKNOWN, f"{name} must be a positive finite number, got {value!r}")
        if not (math.isfinite(self.same_course_tolerance) and self.same_course_tolerance >= 0.0):
            raise FollowPathError(Nav2Error.UNKNOWN, "same_course_tolerance must be a finite number >= 0, got "
                                  f"{self.same_course_tolerance!r}")

    def check_ids(self, controller_id: str, goal_checker_id: str, progress_checker_id: str) -> None:
        """Raise INVALID_CONTROLLER for an id this server does not have ('' is the configured one)."""
        for what, asked, have in (("controller", controller_id, self.controller_id),
                                  ("goal checker", goal_checker_id, self.goal_checker_id),
                                  ("progress checker", progress_checker_id, self.progress_checker_id)):
            if asked not in ("", have):
                raise FollowPathError(Nav2Error.INVALID_CONTROLLER, f"unknown {what} id {asked!r} (this server "
                                      f"has {have!r})")


@dataclass(frozen=True)
class Outcome:
    """How a goal ended: ``succeeded``, ``aborted`` or ``canceled``, Nav2's code and a message."""

    status: str
    code: Nav2Error
    message: str


def _moved(a: Rigid, b: Rigid) -> bool:
    """Whether two planar transforms differ by more than `CORRECTION_M` or `CORRECTION_RAD`."""
    (ax, ay, ayaw), (bx, by, byaw) = a.planar(), b.planar()
    return math.hypot(ax - bx, ay - by) > CORRECTION_M or abs(math.remainder(ayaw - byaw, math.tau)) > CORRECTION_RAD


class PathFollower:
    """One goal at a time of Nav2's FollowPath over `reference` (see the module docstring).

    Parameters
    ----------
    reference
        The goals reference the trajectory node streams; the follower adds its pieces.
    odom_frame
        The frame the reference is in (``<frame_prefix>odom``).
    lookup
        The newest planar transforms (`Lookup`).
    settings
        Ids and checks.

    Attributes
    ----------
    active
        Whether a goal runs (from `start` until `step` returns its `Outcome`).
    """

    def __init__(self, reference: GoalReference, odom_frame: str, lookup: Lookup,
                 settings: FollowPathSettings) -> None:
        self.reference, self.odom_frame, self.lookup, self.settings = reference, odom_frame, lookup, settings
        self.active = False
        self.canceling: Outcome | None = None  # the outcome once the braking reference is at rest
        self.frame = ""
        self.poses = np.zeros((0, 3))  # the goal's path in its own frame (x, y, yaw)
        self.transform = Rigid.identity()  # T_odom_path, as last followed
        self.reached = 0  # index of the nearest pose the reference has reached
        self.baseline: tuple[float, float, float] | None = None  # progress checker: (x, y, t) to move away from
        self.feedback_at = -math.inf  # reference time the next feedback is due

    # goals -----------------------------------------------------------------------------------------
    def start(self, t: float, frame_id: str, poses: np.ndarray, ids: tuple[str, str, str],
              limits: MotionLimits) -> None:
        """Follow a new goal's path from reference time `t` (replacing a running goal's, without a step).

        `poses` (m, 3): (x, y, yaw) in `frame_id`, yaw from each pose's quaternion (checked by the caller).

        Raises
        ------
        FollowPathError
            INVALID_CONTROLLER, INVALID_PATH, TF_ERROR or NO_VALID_CONTROL (module docstring); the reference and a
            running goal are then unchanged (`refuse` ends the running goal).
        """
        self.settings.check_ids(*ids)
        pts = np.asarray(poses, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise FollowPathError(Nav2Error.INVALID_PATH, f"the path has no poses (shape {pts.shape})")
        if not np.isfinite(pts).all():
            raise FollowPathError(Nav2Error.INVALID_PATH, "the path has a non-finite pose")
        frame = frame_id.lstrip("/")
        if not frame:
            raise FollowPathError(Nav2Error.INVALID_PATH, "the path has no frame_id")
        transform = self._lookup(frame)
        reached = self._nearest(t, pts, transform, 0)
        self._follow(t, transform, pts, reached, limits, self.active and self.canceling is None)
        self.active, self.canceling, self.frame, self.poses = True, None, frame, pts
        self.reached, self.baseline, self.feedback_at = reached, None, -math.inf

    def cancel(self, t: float, limits: MotionLimits) -> None:
        """Brake to rest within `limits`; `step` returns CANCELED once the reference is at rest."""
        self._brake(t, limits)
        self.canceling = Outcome("canceled", Nav2Error.NONE, "canceled: braked to rest")

    def refuse(self, t: float, limits: MotionLimits, error: FollowPathError) -> Outcome:
        """End a running goal because a new one was refused (Nav2 ends both): brake to rest; the new goal's outcome."""
        if self.active:
            self._brake(t, limits)
            self.active = False
        return Outcome("aborted", error.code, str(error))

    def step(self, t: float, robot: tuple[float, float, float] | None, limits: MotionLimits) -> Outcome | None:
        """One control period at reference time `t` with the robot's pose in odom (None: none yet); the outcome once
        the goal has ended (then `active` is False), else None.
        """
        if not self.active:
            return None
        if self.canceling is not None:
            return self._end(self.canceling) if t >= self.reference.motion_end_s else None
        try:
            transform = self._lookup(self.frame)
            self.reached = self._nearest(t, self.poses, self.transform, self.reached)
            if _moved(transform, self.transform):
                self._follow(t, transform, self.poses, self.reached, limits, True)
        except FollowPathError as exc:
            self._brake(t, limits)
            return self._end(Outcome("aborted", exc.code, str(exc)))
        if robot is None:
            return None
        if t >= self.reference.motion_end_s and self._at_goal(robot):
            return self._end(Outcome("succeeded", Nav2Error.NONE, "reached the goal"))
        x, y, _ = robot
        if self.baseline is None or math.hypot(x - self.baseline[0], y - self.baseline[1]) > \
                self.settings.required_movement_radius:
            self.baseline = (x, y, t)
        elif t - self.baseline[2] > self.settings.movement_time_allowance:
            self._brake(t, limits)
            return self._end(Outcome("aborted", Nav2Error.FAILED_TO_MAKE_PROGRESS, (
                f"the robot moved less than {self.settings.required_movement_radius:g} m in "
                f"{self.settings.movement_time_allowance:g} s")))
        return None

    def due_feedback(self, t: float, robot: tuple[float, float, float] | None) -> tuple[float, float] | None:
        """`feedback` every `FEEDBACK_PERIOD_S` of reference time from a goal's start, on that grid however the
        periods fall (None between).
        """
        due = self.feedback_at
        if t < due - 1e-9:
            return None
        self.feedback_at = due + FEEDBACK_PERIOD_S if t < due + FEEDBACK_PERIOD_S else t + FEEDBACK_PERIOD_S
        return self.feedback(t, robot)

    def feedback(self, t: float, robot: tuple[float, float, float] | None) -> tuple[float, float]:
        """(distance_to_goal [m], speed [m/s]): the path's length from the pose nearest the robot (the reference
        without a robot pose) to its end, as Nav2 measures it, and the reference's speed |(x', y')| at `t`.
        """
        odom = transform_planar(self.transform, self.poses)
        state = self.reference.state(t)
        here = np.asarray(robot[:2]) if robot is not None else state[0, :2]
        nearest = int(np.argmin(np.hypot(*(odom[:, :2] - here).T)))
        remaining = float(np.sum(np.hypot(*np.diff(odom[nearest:, :2], axis=0).T)))
        vx, vy = state[1, :2]
        return remaining, math.hypot(vx, vy)

    # the reference -----------------------------------------------------------------------------------
    def _lookup(self, frame: str) -> Rigid:
        """T_odom_frame, planar; TF_ERROR if there is none."""
        try:
            transform = self.lookup(self.odom_frame, frame)
            transform.planar()
            return transform
        except FrameError as exc:
            raise FollowPathError(Nav2Error.TF_ERROR, f"no transform from {frame!r} to {self.odom_frame!r}: "
                                  f"{exc}") from None

    def _nearest(self, t: float, poses: np.ndarray, transform: Rigid, start: int) -> int:
        """Index of the pose (in its frame, which `transform` takes to odom) nearest the reference's position at
        `t`, searched from `start` within `PRUNE_WINDOW_M` of path length.
        """
        x, y, _ = transform_planar(transform.inverse(), self.reference.state(t)[0])
        ahead = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(poses[start:, :2], axis=0).T))))
        window = poses[start:][ahead <= PRUNE_WINDOW_M]
        return start + int(np.argmin(np.hypot(window[:, 0] - x, window[:, 1] - y)))

    def _follow(self, t: float, transform: Rigid, poses: np.ndarray, reached: int, limits: MotionLimits,
                moving: bool) -> None:
        """Follow poses[reached + 1:] (the last pose if none is left) moved into odom by `transform`; while `moving`
        (a goal runs) a path on the same course moves the reference's end instead (module docstring).
        """
        rest = poses[reached + 1:] if reached + 1 < len(poses) else poses[-1:]
        odom = transform_planar(transform, rest)
        theta = float(self.reference.state(t)[0, 2])
        for k in range(len(odom)):  # headings unwrapped pose by pose from the reference's
            theta = odom[k, 2] = theta + math.remainder(odom[k, 2] - theta, math.tau)
        if not self.settings.use_path_orientations:  # from the heading now to the last pose's, along the path
            here = self.reference.state(t)[0]
            xy = np.vstack((here[:2], odom[:, :2]))
            along = np.cumsum(np.hypot(*np.diff(xy, axis=0).T))
            share = along / along[-1] if along[-1] > 0.0 else np.ones(len(odom))
            odom[:, 2] = here[2] + share * (odom[-1, 2] - here[2])
        if moving and self._same_course(t, odom, limits.robot.l):
            end = self.reference.state(self.reference.motion_end_s)[0]
            try:
                self.reference.shift(t, odom[-1] - end, limits)
                self.transform = transform
                return
            except GoalError:
                pass  # the shift would leave the limits: retimed below
        try:
            self.reference.follow(t, odom, limits)
        except GoalError as exc:
            raise FollowPathError(Nav2Error.NO_VALID_CONTROL, f"no motion along the path within the limits: "
                                  f"{exc}") from None
        self.transform = transform

    def _same_course(self, t: float, poses: np.ndarray, weight: float) -> bool:
        """Whether every pose (in odom) lies within ``same_course_tolerance`` of the reference's course from t on and
        the last one of its end, heading included (|(dx, dy, `weight` dtheta)|, `weight` the wheel distance: a turn
        counted as the wheels roll it).
        """
        tolerance = self.settings.same_course_tolerance
        end = self.reference.motion_end_s
        if tolerance == 0.0 or end <= t or \
                np.linalg.norm((poses[-1] - self.reference.state(end)[0]) * [1.0, 1.0, weight]) > tolerance:
            return False
        course = self.reference.position(np.linspace(t, end, 300))[:, :2]
        a, b = course[:-1], course[1:]
        ab = b - a
        length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
        for x, y, _ in poses:  # distance to the course: to its nearest segment
            along = np.clip(((x - a[:, 0]) * ab[:, 0] + (y - a[:, 1]) * ab[:, 1]) / length2, 0.0, 1.0)
            if np.min(np.hypot(a[:, 0] + along * ab[:, 0] - x, a[:, 1] + along * ab[:, 1] - y)) > tolerance:
                return False
        return True

    def _at_goal(self, robot: tuple[float, float, float]) -> bool:
        gx, gy, gyaw = transform_planar(self.transform, self.poses[-1])
        return math.hypot(robot[0] - gx, robot[1] - gy) <= self.settings.xy_goal_tolerance and \
            abs(math.remainder(robot[2] - gyaw, math.tau)) <= self.settings.yaw_goal_tolerance

    def _brake(self, t: float, limits: MotionLimits) -> None:
        """Brake the reference to rest (`GoalReference.stop`; its GoalError, which a reference within the limits
        never gives, passes up).
        """
        self.reference.stop(t, limits)

    def _end(self, outcome: Outcome) -> Outcome:
        self.active, self.canceling = False, None
        return outcome
