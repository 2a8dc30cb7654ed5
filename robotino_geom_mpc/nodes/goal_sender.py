"""Goal sender: publishes the timed goals and paths of a goal file as a user (RViz) and a planner (Nav2) would.

``run --scenario goals --goals FILE`` starts it beside the loop, so the trajectory node's goal topics are
exercised over DDS. Publishes ``goal_pose`` (geometry_msgs/PoseStamped) and ``plan`` (nav_msgs/Path),
reliable, keep-last 10, volatile (`nodes.goal_inputs.GOAL_QOS`); subscribes ``odom`` (best effort, depth 1:
never holds the loop back) for the time: an item of `reference.goal_file` is sent at the first odometry stamped
``t`` after the run's start (lockstep: the simulated time 0; realtime: the first odometry it receives).
Headers are stamped with that odometry stamp and carry the item's ``frame``.

Parameters: ``goals_file`` (path of the goal file), ``mode`` (realtime or lockstep).
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from robotino_geom_mpc.reference.goal_file import GoalItem, load_goal_file
from robotino_geom_mpc.reference.goal_motion import GoalError
from robotino_geom_mpc.params.specs import ParamSpec
from robotino_geom_mpc.nodes.goal_inputs import GOAL_QOS
from robotino_geom_mpc.ros.messages import stamp_to_ns, yaw_to_quaternion
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters
from robotino_geom_mpc.ros.spin import run_node

__all__ = ["SENDER_SPECS", "GoalSender", "main"]

SENDER_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("goals_file", str, "Goal file (YAML or JSON, see reference.goal_file) whose items the node sends"),
    ParamSpec("mode", str, "lockstep: item times from simulated time 0; realtime: from the first odometry",
              choices=("realtime", "lockstep")),
)
_TIME_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


def _pose(item_frame: str, stamp, x: float, y: float, yaw: float) -> PoseStamped:  # noqa: ANN001
    msg = PoseStamped()
    msg.header.frame_id, msg.header.stamp = item_frame, stamp
    msg.pose.position.x, msg.pose.position.y = x, y
    msg.pose.orientation = yaw_to_quaternion(yaw)
    return msg


class GoalSender(Node):
    """The goal sender (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("robotino_goal_sender", **kwargs)
        self.params = SpecParameters(self, SENDER_SPECS, {"goals_file": "", "mode": "realtime"}, fixed=("goals_file",))
        try:
            self.items: list[GoalItem] = load_goal_file(self.params["goals_file"])
        except GoalError as exc:
            raise NodeStartError(str(exc)) from None
        self.start_ns: int | None = 0 if self.params["mode"] == "lockstep" else None
        self.goal_pub = self.create_publisher(PoseStamped, "goal_pose", GOAL_QOS)
        self.plan_pub = self.create_publisher(Path, "plan", GOAL_QOS)
        self.create_subscription(Odometry, "odom", self._on_odom, _TIME_QOS)
        self.get_logger().info(f"{len(self.items)} goal file item(s) from {self.params['goals_file']}")

    def _on_odom(self, msg: Odometry) -> None:
        now = stamp_to_ns(msg.header.stamp)
        if self.start_ns is None:
            self.start_ns = now
        while self.items and now - self.start_ns >= int(self.items[0].t * 1e9):
            item = self.items.pop(0)
            poses = [_pose(item.frame, msg.header.stamp, *p) for p in item.poses]
            if item.is_path:
                path = Path()
                path.header = poses[0].header
                path.poses = poses
                self.plan_pub.publish(path)
            else:
                self.goal_pub.publish(poses[0])
            kind = "path" if item.is_path else "goal"
            self.get_logger().info(f"sent {kind} of t = {item.t:g} s at {(now - self.start_ns) * 1e-9:.3f} s")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``python -m robotino_geom_mpc.nodes.goal_sender``."""
    return run_node(GoalSender, args)


if __name__ == "__main__":
    raise SystemExit(main())
