"""The trajectory node's ``follow_path`` action server (nav2_msgs/action/FollowPath): Nav2's controller_server role.

Action ``follow_path`` (relative name: remappable, ``<namespace>/follow_path`` in a namespace), offered from the
first time the scenario is ``goals`` and served while it is (goals are rejected otherwise, and before an anchored
reference has started). What a goal does, how
it ends and with which error code is `reference.follow_path` (`PathFollower`); this module decodes goals, keeps
the goal handles and answers:

- a goal's poses are checked here (finite, quaternion a rotation about z: else INVALID_PATH) and handed to
  `PathFollower.start` at the node's reference time; a goal while another runs replaces it, and the old one ends
  ABORTED with error NONE and "preempted" (Nav2's SimpleActionServer does the same); a new goal that is refused
  ends the running one too, braking the robot to rest (as Nav2 stops it);
- each control period (`tick`, called by the node when it publishes a preview) the follower steps with the robot's
  pose from ``odom``; feedback (``distance_to_goal``, ``speed``) every
  `reference.follow_path.FEEDBACK_PERIOD_S`;
- a cancel of the running goal is accepted: the reference brakes to rest, then the goal ends CANCELED.

Parameters (`FOLLOW_PATH_SPECS`, ``follow_path.*``): the controller, goal checker and progress checker ids this
server answers to and SimpleGoalChecker's and SimpleProgressChecker's parameters under their Nav2 names; read
at each goal and each period.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable
from typing import Any

import numpy as np
from nav2_msgs.action import FollowPath
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node
from rclpy.task import Future

from robotino_geom_mpc.nodes.goal_inputs import pose_of
from robotino_geom_mpc.params.specs import ParamSpec
from robotino_geom_mpc.reference.follow_path import FollowPathError, FollowPathSettings, Lookup, Nav2Error, \
    Outcome, PathFollower
from robotino_geom_mpc.reference.goal_file import motion_limits
from robotino_geom_mpc.reference.goal_motion import GoalError
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.ros.decode import InputRejected

__all__ = ["FOLLOW_PATH_DEFAULTS", "FOLLOW_PATH_SPECS", "FollowPathServer",
           "follow_path_settings"]

def _positive(name: str, what: str, unit: str) -> ParamSpec:
    return ParamSpec(f"follow_path.{name}", float, f"follow_path: {what}", unit, 0.0, 1e6, True)


FOLLOW_PATH_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("follow_path.controller_id", str, "follow_path: the controller_id goals may ask for ('' too)"),
    ParamSpec("follow_path.goal_checker_id", str, "follow_path: the goal_checker_id goals may ask for ('' too)"),
    ParamSpec("follow_path.progress_checker_id", str, "follow_path: the progress_checker_id goals may ask for "
              "('' too)"),
    _positive("xy_goal_tolerance", "success needs the robot this close to the path's end (SimpleGoalChecker)", "m"),
    _positive("yaw_goal_tolerance", "success needs the robot's heading this close to the path's end's", "rad"),
    _positive("required_movement_radius", "the robot moves this far within movement_time_allowance, or the goal "
              "fails with FAILED_TO_MAKE_PROGRESS (SimpleProgressChecker)", "m"),
    _positive("movement_time_allowance", "see required_movement_radius", "s"),
    ParamSpec("follow_path.same_course_tolerance", float, "follow_path: a new path within this distance of the "
              "reference's course (a replan of the same route, a localization correction) moves the reference's end "
              "instead of retiming the path; 0: every new path is retimed", "m", 0.0, 10.0, False),
    ParamSpec("follow_path.use_path_orientations", bool, "follow_path: true: the heading passes through each pose's "
              "(Smac, a smoother); false (as MPPI's default): it turns from the robot's to the last pose's along the "
              "path (NavFn leaves the others at yaw 0)"),
)
_DEFAULT_SETTINGS = FollowPathSettings()
FOLLOW_PATH_DEFAULTS: dict[str, Any] = {spec.name: getattr(_DEFAULT_SETTINGS, spec.attr) for spec in FOLLOW_PATH_SPECS}


def follow_path_settings(values: dict[str, Any]) -> FollowPathSettings:
    """The `FollowPathSettings` of the node's parameter values."""
    return FollowPathSettings(**{spec.attr: values[spec.name] for spec in FOLLOW_PATH_SPECS})


def _result(outcome: Outcome) -> FollowPath.Result:
    return FollowPath.Result(error_code=int(outcome.code), error_msg=outcome.message)


class FollowPathServer:
    """The action server of the module docstring.

    Parameters
    ----------
    node
        The trajectory node (its logger and executor).
    values
        The node's parameter values (limits, ``follow_path.*``).
    reference_time
        The node's reference time [s] now (a goal starts there).
    robot_pose
        The robot's newest pose (x, y, yaw) in odom, or None.
    replanned
        Called after the follower changed the reference (the node publishes the new path).
    lookup
        The newest planar transforms (`reference.follow_path.Lookup`).
    odom_frame
        The reference's frame.
    """

    def __init__(self, node: Node, values: dict[str, Any], reference_time: Callable[[], float],
                 robot_pose: Callable[[], tuple[float, float, float] | None],
                 replanned: Callable[[GoalReference], None], lookup: Lookup, odom_frame: Callable[[], str]) -> None:
        self._node, self._values, self._time, self._robot = node, values, reference_time, robot_pose
        self._replanned, self._lookup, self._odom_frame = replanned, lookup, odom_frame
        self.follower: PathFollower | None = None
        self.goal: ServerGoalHandle | None = None  # the running goal
        self._done: Future | None = None  # its result, awaited by `_execute`
        self.server: ActionServer | None = None  # made at the first goals reference (none in other scenarios)

    def attach(self, reference: object) -> None:
        """Serve goals over `reference` if it is a `GoalReference` (a running goal on another one is aborted)."""
        if self.follower is not None and self.follower.reference is reference:
            return
        self._finish(Outcome("aborted", Nav2Error.UNKNOWN, "the node's reference was made anew (a new scenario, "
                             "or the controller's disable)"))
        self.follower = None if not isinstance(reference, GoalReference) else \
            PathFollower(reference, self._odom_frame(), self._lookup, follow_path_settings(self._values))
        if self.follower is not None and self.server is None:
            self.server = ActionServer(self._node, FollowPath, "follow_path", execute_callback=self._execute,
                                       goal_callback=self._on_goal, cancel_callback=self._on_cancel)

    # action callbacks ----------------------------------------------------------------------------
    def _on_goal(self, _request: FollowPath.Goal) -> GoalResponse:
        if self.follower is None:
            self._node.get_logger().warn("follow_path goal rejected: the scenario is not 'goals' (or the reference "
                                         "has not started)")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_cancel(self, handle: ServerGoalHandle) -> CancelResponse:
        return CancelResponse.ACCEPT if handle is self.goal else CancelResponse.REJECT

    async def _execute(self, handle: ServerGoalHandle) -> FollowPath.Result:
        follower = self.follower
        if follower is None:  # the scenario changed between acceptance and execution
            handle.abort()
            return FollowPath.Result(error_code=int(Nav2Error.UNKNOWN), error_msg="the scenario is not 'goals'")
        goal: FollowPath.Goal = handle.request
        t, limits = self._time(), motion_limits(self._values)
        follower.settings = follow_path_settings(self._values)
        follower.odom_frame = self._odom_frame()
        try:
            poses = self._poses(goal)
            follower.start(t, goal.path.header.frame_id, poses,
                           (goal.controller_id, goal.goal_checker_id, goal.progress_checker_id), limits)
        except Exception as error:  # a refused goal, or a fault planning it: the goal ends, the node goes on
            exc = error if isinstance(error, FollowPathError) else self._fault(error)
            running = follower.active
            outcome = follower.refuse(t, limits, exc)
            if running:
                self._finish(Outcome("aborted", Nav2Error.NONE, "preempted by a goal that was refused: braking to "
                                     "rest"))
                self._replanned(follower.reference)
            self._node.get_logger().warn(f"follow_path goal refused ({exc.code.name}): {exc}")
            handle.abort()
            return _result(outcome)
        self._finish(Outcome("aborted", Nav2Error.NONE, "preempted by a new goal"))
        self.goal, self._done = handle, Future()
        self._node.get_logger().info(f"follow_path: {len(poses)} poses in {goal.path.header.frame_id!r} from "
                                     f"t = {t:.3f} s, until t = {follower.reference.motion_end_s:.3f} s")
        self._replanned(follower.reference)
        result = await self._done
        return result

    @staticmethod
    def _poses(goal: FollowPath.Goal) -> np.ndarray:
        """(m, 3) (x, y, yaw) of the path's poses; INVALID_PATH for a non-finite or tilted one."""
        try:
            return np.array([pose_of(stamped.pose, f"path pose {k}") for k, stamped in enumerate(goal.path.poses)],
                            dtype=float).reshape(-1, 3)
        except InputRejected as exc:
            raise FollowPathError(Nav2Error.INVALID_PATH, str(exc)) from None

    # each control period ----------------------------------------------------------------------------
    def tick(self) -> None:
        """One control period: cancel, step, feedback and the end of the running goal."""
        follower, handle = self.follower, self.goal
        if follower is None or handle is None:
            return
        t, limits = self._time(), motion_limits(self._values)
        robot = self._robot()
        pieces = list(follower.reference.pieces)
        try:
            if handle.is_cancel_requested and follower.canceling is None:
                follower.cancel(t, limits)
            follower.settings = follow_path_settings(self._values)
            outcome = follower.step(t, robot, limits)
        except Exception as error:  # a fault in the follower (a stop no timing keeps): the goal ends, the node goes on
            exc = self._fault(error)
            follower.active = False
            outcome = Outcome("aborted", exc.code, str(exc))
        if follower.reference.pieces != pieces:  # a correction's replan, a stop: the node publishes it
            self._replanned(follower.reference)
        if outcome is not None:
            self._finish(outcome)
            return
        feedback = follower.due_feedback(t, robot)
        if feedback is not None:
            handle.publish_feedback(FollowPath.Feedback(distance_to_goal=feedback[0], speed=feedback[1]))

    def _fault(self, error: Exception) -> FollowPathError:
        """A fault in the follower, logged with its traceback, as Nav2's error (NO_VALID_CONTROL for a motion no
        timing keeps within the limits, else UNKNOWN).
        """
        self._node.get_logger().error(f"follow_path: {type(error).__name__}: {error}\n{traceback.format_exc()}")
        code = Nav2Error.NO_VALID_CONTROL if isinstance(error, GoalError) else Nav2Error.UNKNOWN
        return FollowPathError(code, f"{type(error).__name__}: {error}")

    def _finish(self, outcome: Outcome) -> None:
        """End the running goal (if any) with `outcome`."""
        handle, done = self.goal, self._done
        self.goal, self._done = None, None
        if handle is None or done is None:
            return
        if handle.is_active:
            {"succeeded": handle.succeed, "canceled": handle.canceled}.get(outcome.status, handle.abort)()
        line = f"follow_path goal {outcome.status} ({outcome.code.name}): {outcome.message}"
        if outcome.status == "succeeded":  # (one severity per call site: rclpy's loggers insist)
            self._node.get_logger().info(line)
        else:
            self._node.get_logger().warn(line)
        done.set_result(_result(outcome))
