"""/tf and /tf_static into a `reference.frames.TransformTree`: tf2_ros's TransformListener, without tf2.

tf2_py is a C++ extension that cannot be installed here; tf2_msgs (TFMessage) can. `TransformListener`
subscribes both topics with tf2_ros's QoS (geometry2, jazzy, tf2_ros_py/tf2_ros/transform_listener.py):

* `TF_QOS` (/tf): keep-last 100, reliable, volatile: the broadcasters' newest transforms.
* `TF_STATIC_QOS` (/tf_static): keep-last 100, reliable, transient local, so a listener that starts after a
  static broadcaster (robot_state_publisher's fixed joints, a sensor mount) still gets its transforms.

Each transform of a message is set into the tree (static from /tf_static): the stamp is checked as the
controller's are (`loop.inputs.time_ns`), the frame ids, values and quaternion by `TransformTree.set`. A refused
transform is skipped, the others of its message are kept; it is counted by reason in `TransformListener.refused`
and logged, at most once per `LOG_PERIOD_S` per topic and reason. The subscriptions have a callback group of
their own, so the tree is updated while the node runs long callbacks of its own (an action server's) on a
multi-threaded executor; the tree is thread-safe.
"""

from __future__ import annotations

from collections import Counter
from functools import partial

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from robotino_geom_mpc.reference.frames import FrameError, TransformTree
from robotino_geom_mpc.ros.decode import InputRejected, time_ns
from robotino_geom_mpc.ros.throttle import log_throttled

__all__ = ["LOG_PERIOD_S", "TF_QOS", "TF_STATIC_QOS", "TransformListener"]

TF_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
TF_STATIC_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
LOG_PERIOD_S = 5.0  # a refused transform is logged at most this often per topic and reason [s]


class TransformListener:
    """Feed every transform of `tf_topic` and `tf_static_topic` into `tree` (see the module docstring).

    Parameters
    ----------
    node
        The node that subscribes (its executor runs the callbacks).
    tree
        The tree to update.
    tf_topic, tf_static_topic
        The topics (a namespaced robot's, e.g. ``tf`` and ``tf_static`` relative to the node's namespace).

    Attributes
    ----------
    refused
        Refused transforms by reason (`reference.frames.FrameError`'s, or ``stamp``).
    """

    def __init__(self, node: Node, tree: TransformTree, tf_topic: str = "/tf",
                 tf_static_topic: str = "/tf_static") -> None:
        self.node, self.tree = node, tree
        self.refused: Counter[str] = Counter()
        group = MutuallyExclusiveCallbackGroup()
        self.tf_subscription = node.create_subscription(
            TFMessage, tf_topic, partial(self._take, tf_topic, False), TF_QOS, callback_group=group)
        self.tf_static_subscription = node.create_subscription(
            TFMessage, tf_static_topic, partial(self._take, tf_static_topic, True), TF_STATIC_QOS,
            callback_group=group)

    def _take(self, topic: str, static: bool, msg: TFMessage) -> None:
        for transform in msg.transforms:
            header, t, q = transform.header, transform.transform.translation, transform.transform.rotation
            try:
                self.tree.set(header.frame_id, transform.child_frame_id, (t.x, t.y, t.z), (q.x, q.y, q.z, q.w),
                              time_ns(header.stamp.sec, header.stamp.nanosec), static)
            except (FrameError, InputRejected) as exc:
                self.refused[exc.reason] += 1
                log_throttled(self.node.get_logger(), "WARN",
                              f"{topic}: transform {header.frame_id!r} -> {transform.child_frame_id!r} refused "
                              f"({exc.reason}): {exc} ({self.refused[exc.reason]} refused for this reason)",
                              LOG_PERIOD_S, f"{topic} {exc.reason}")
