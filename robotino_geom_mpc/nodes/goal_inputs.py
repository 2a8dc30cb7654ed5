"""The trajectory node's goal inputs (scenario ``goals``): goal_pose and plan, checked, turned into goal motions.

Topics (relative names), subscribed only while the scenario is ``goals``
-----------------------------------------------------------------------
``goal_pose``  geometry_msgs/PoseStamped (what RViz's "2D Goal Pose" sends): move to the pose and rest there.
``plan``       nav_msgs/Path (what a Nav2 planner publishes): follow the poses, heading as they give it, and
               rest at the last.

Both reliable, keep-last 10, volatile (RViz's and Nav2's publishers). A goal or path starts a new motion of
`reference.goals.GoalReference` at the node's current reference time from the reference's full state there
(`GoalReference.go_to`, `GoalReference.follow`), so a goal during a motion takes over without a jump in
position, velocity or acceleration. Headings (yaw of the poses' quaternions) are unwrapped to the nearest
turn: a goal's to the reference's heading (the shorter rotation), a path's pose by pose.

Refused, with a warning naming the reason and the reference unchanged (the robot holds or goes on): a frame
other than ``<frame_prefix>odom`` (this node has no transforms; an empty frame_id is refused too), a
non-finite position, a quaternion that is not a unit rotation about z (`ros.decode.check_yaw_quaternion`), an
empty path, and a motion no duration up to 600 s keeps within the limits (`reference.goal_motion.GoalError`).

Limits (`GOAL_SPECS`: `reference.goal_file.LIMIT_SPECS` and ``frame_prefix``): per axis velocity, acceleration and
jerk (x and y share the linear ones) and the
wheels' rim speed; ``goals.max_rim_speed_mps`` = 0 takes the motor's nominal speed at the rim
(`reference.goal_motion.nominal_rim_speed`, 0.94 m/s on Robotino 3); the defaults and their currents are
`reference.goal_file`'s.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import Pose, PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from robotino_geom_mpc.reference.goal_file import LIMIT_DEFAULTS, LIMIT_SPECS, motion_limits
from robotino_geom_mpc.reference.goal_motion import GoalError
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.params.specs import ParamError, ParamSpec
from robotino_geom_mpc.description.urdf import DescriptionError, check_frame_prefix
from robotino_geom_mpc.ros.decode import InputRejected, check_yaw_quaternion, unwrap_near, yaw_of
from robotino_geom_mpc.ros.messages import ODOM_FRAME

__all__ = ["GOAL_SPECS", "GOAL_DEFAULTS", "GOAL_QOS", "GoalInputs", "goal_params_problem", "pose_of"]

GOAL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
GOAL_SPECS: tuple[ParamSpec, ...] = LIMIT_SPECS + (
    ParamSpec("frame_prefix", str, "Prefix of the odom frame goals and paths must be given in (e.g. 'robot1/'; "
              "'' for 'odom')"),
)
GOAL_DEFAULTS: dict[str, Any] = {**LIMIT_DEFAULTS, "frame_prefix": ""}


def goal_params_problem(values: dict[str, Any]) -> str | None:
    """Why the goal parameters in `values` are refused (a bad frame prefix or limits), or None."""
    try:
        check_frame_prefix(values["frame_prefix"])
        motion_limits(values)
    except (DescriptionError, GoalError, ParamError) as exc:
        return str(exc)
    return None


def pose_of(pose: Pose, what: str) -> tuple[float, float, float]:
    """(x, y, yaw) of a pose checked as the module docstring says (`InputRejected` naming `what` otherwise)."""
    p, q = pose.position, pose.orientation
    if not all(math.isfinite(v) for v in (p.x, p.y, p.z)):
        raise InputRejected(f"{what} position ({p.x:g}, {p.y:g}, {p.z:g}) is not finite", "non_finite")
    check_yaw_quaternion(q.x, q.y, q.z, q.w, what)
    return p.x, p.y, yaw_of(q.x, q.y, q.z, q.w)


class GoalInputs:
    """The goal_pose and plan subscriptions of a trajectory node and their checks (see the module docstring).

    Parameters
    ----------
    node
        The trajectory node (its logger; `reference_time` and `replanned` are its).
    values
        The node's current parameter values (read at each goal: limits and frame prefix).
    reference_time
        The node's current reference time [s] (0 before the reference starts).
    replanned
        Called after the reference changed (the node refreshes what it derived from it).
    """

    def __init__(self, node: Node, values: dict[str, Any], reference_time: Callable[[], float],
                 replanned: Callable[[GoalReference], None]) -> None:
        self._node, self._values = node, values
        self._time, self._replanned = reference_time, replanned
        self.reference: GoalReference | None = None
        self._subs: list = []
        self.refused: dict[str, int] = {}  # refusals by reason key

    def attach(self, reference: object) -> None:
        """Follow `reference` if it is a `GoalReference` (subscribing the topics), else drop the subscriptions."""
        self.reference = reference if isinstance(reference, GoalReference) else None
        if self.reference is not None and not self._subs:
            self._subs = [self._node.create_subscription(PoseStamped, "goal_pose", self._on_goal, GOAL_QOS),
                          self._node.create_subscription(Path, "plan", self._on_plan, GOAL_QOS)]
        elif self.reference is None:
            for sub in self._subs:
                self._node.destroy_subscription(sub)
            self._subs = []

    # checks -------------------------------------------------------------------------------------
    def _frame(self, frame_id: str, what: str) -> None:
        odom = self._values["frame_prefix"] + ODOM_FRAME
        if frame_id != odom:
            raise InputRejected(f"{what} is in frame {frame_id!r}, not {odom!r} (no transform to it)", "frame")

    def _refuse(self, what: str, exc: Exception) -> None:
        reason = getattr(exc, "reason", "unreachable")
        self.refused[reason] = self.refused.get(reason, 0) + 1
        self._node.get_logger().warn(f"{what} refused ({reason}): {exc}; the reference is unchanged")

    # callbacks ----------------------------------------------------------------------------------
    def _on_goal(self, msg: PoseStamped) -> None:
        if self.reference is None:
            return
        t = self._time()
        try:
            self._frame(msg.header.frame_id, "goal")
            x, y, yaw = pose_of(msg.pose, "goal")
            theta = unwrap_near(yaw, float(self.reference.state(t)[0, 2]))
            motion = self.reference.go_to(t, np.array([x, y, theta]), motion_limits(self._values))
        except (InputRejected, GoalError) as exc:
            self._refuse("goal", exc)
            return
        took = 0.0 if motion is None else motion.duration_s
        self._node.get_logger().info(f"goal ({x:.4g} m, {y:.4g} m, {theta:.4g} rad) from t = {t:.3f} s, "
                                     f"{took:.3g} s")
        self._replanned(self.reference)

    def _on_plan(self, msg: Path) -> None:
        if self.reference is None:
            return
        t = self._time()
        try:
            if not msg.poses:
                raise InputRejected("path has no poses", "empty")
            self._frame(msg.header.frame_id, "path")
            poses, theta = [], float(self.reference.state(t)[0, 2])
            for k, stamped in enumerate(msg.poses):
                if stamped.header.frame_id:  # a pose's own frame, if given, must be the path's
                    self._frame(stamped.header.frame_id, f"path pose {k}")
                x, y, yaw = pose_of(stamped.pose, f"path pose {k}")
                theta = unwrap_near(yaw, theta)
                poses.append((x, y, theta))
            motion = self.reference.follow(t, np.array(poses), motion_limits(self._values))
        except (InputRejected, GoalError) as exc:
            self._refuse("path", exc)
            return
        self._node.get_logger().info(f"path of {len(poses)} poses from t = {t:.3f} s, {motion.duration_s:.3g} s")
        self._replanned(self.reference)
