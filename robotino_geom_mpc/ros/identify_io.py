"""`identify --ros`: the robot's driver topics as a `control.chain_identification.RobotIO` (rclpy).

A node ``robotino_identify`` subscribes the driver's odometry (nav_msgs/Odometry, reliable, depth 50: two
samples of one driver pass arrive together) and publishes geometry_msgs/Twist on its cmd_vel; it starts once
the driver subscribes that and its odometry flows (`RosRobot.wait_ready`). `poll` spins
until odometry has arrived and returns the node clock's time with the messages (stamp in seconds, pose
(x, y, yaw) in odom, twist in base_link); no odometry for `ODOM_WAIT_S` stops the robot and raises
`IdentifyError`. Leaving the context publishes zero twists and ends rclpy.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Iterator

from robotino_geom_mpc.control.chain_identification import IdentifyError
from robotino_geom_mpc.loop.inputs import yaw_of

__all__ = ["ODOM_WAIT_S", "RosRobot", "ros_robot"]

ODOM_WAIT_S = 1.0
READY_WAIT_S = 15.0  # discovery: the driver's cmd_vel subscription matched and its odometry flowing
_ZEROS_AT_EXIT = 5


class RosRobot:
    """The driver's topics (module docstring)."""

    def __init__(self, node, odom_topic: str, cmd_vel_topic: str) -> None:  # noqa: ANN001 - an rclpy Node
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.node, self._twist = node, Twist
        self.pub = node.create_publisher(Twist, cmd_vel_topic, 10)
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.sub = node.create_subscription(Odometry, odom_topic, self._on_odom, qos)
        self.inbox: list[tuple[float, tuple, tuple]] = []
        self.odom_topic = odom_topic

    def _on_odom(self, msg) -> None:  # noqa: ANN001 - nav_msgs/Odometry
        q = msg.pose.pose.orientation
        yaw = yaw_of(q.x, q.y, q.z, q.w)
        p, t = msg.pose.pose.position, msg.twist.twist
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        self.inbox.append((stamp, (p.x, p.y, yaw), (t.linear.x, t.linear.y, t.angular.z)))

    def poll(self) -> tuple[float, list[tuple[float, tuple, tuple]]]:
        """Spin until odometry has arrived: (node clock [s], the messages since the last poll)."""
        import rclpy

        deadline = time.monotonic() + ODOM_WAIT_S
        while not self.inbox:
            if time.monotonic() > deadline:
                self.send((0.0, 0.0, 0.0))
                raise IdentifyError(f"no odometry on {self.odom_topic} for {ODOM_WAIT_S:g} s; the robot was stopped")
            rclpy.spin_once(self.node, timeout_sec=0.01)
        messages, self.inbox = self.inbox, []
        return self.node.get_clock().now().nanoseconds * 1e-9, messages

    def wait_ready(self, timeout_s: float = READY_WAIT_S) -> None:
        """Spin until the driver subscribes our cmd_vel and its odometry arrives; IdentifyError after `timeout_s`
        (a command published before discovery matched it would be lost: the excitation would seem not to move).
        """
        import rclpy

        deadline = time.monotonic() + timeout_s
        while not (self.pub.get_subscription_count() > 0 and self.inbox):
            if time.monotonic() > deadline:
                raise IdentifyError(f"after {timeout_s:g} s: {self.pub.get_subscription_count()} subscribers of "
                                    f"{self.pub.topic_name}, {len(self.inbox)} odometry messages on "
                                    f"{self.odom_topic}; is the driver running?")
            rclpy.spin_once(self.node, timeout_sec=0.05)
        self.inbox = []

    def send(self, twist: tuple[float, float, float]) -> None:
        """Publish a cmd_vel now."""
        msg = self._twist()
        msg.linear.x, msg.linear.y, msg.angular.z = (float(v) for v in twist)
        self.pub.publish(msg)


@contextmanager
def ros_robot(odom_topic: str = "odom", cmd_vel_topic: str = "cmd_vel") -> Iterator[RosRobot]:
    """rclpy up, a `RosRobot`, and at the end zero twists and rclpy down."""
    import rclpy

    rclpy.init()
    node = rclpy.create_node("robotino_identify")
    robot = RosRobot(node, odom_topic, cmd_vel_topic)
    try:
        robot.wait_ready()
        yield robot
    finally:
        for _ in range(_ZEROS_AT_EXIT):
            robot.send((0.0, 0.0, 0.0))
            rclpy.spin_once(node, timeout_sec=0.01)
        node.destroy_node()
        rclpy.try_shutdown()
