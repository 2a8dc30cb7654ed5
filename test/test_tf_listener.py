"""ros.tf_listener over DDS, in process: /tf_static published before the listener exists, /tf after, a NaN refused.

The truth is independent of the module: the published translations and quaternions as 4x4 homogeneous matrices
(scipy's `Rotation`), multiplied along the chain.
"""

import math
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import TransformStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from scipy.spatial.transform import Rotation

from robotino_geom_mpc.reference.frames import FrameError, TransformTree
from robotino_geom_mpc.ros.tf_listener import TF_QOS, TF_STATIC_QOS, TransformListener

pytestmark = pytest.mark.ros

tf2_msgs = pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs not installed ('make setup' builds it)")

TIMEOUT_S = 10.0
SECOND = 1_000_000_000
DYNAMIC_NS, MOVED_NS = 100 * SECOND + 250_000_000, 101 * SECOND + 500_000_000  # the stamps of the /tf messages
RNG = np.random.default_rng(7)
# (parent, child, translation, quaternion x, y, z, w): 3D rotations, as a sensor mount's
STATIC = [("base_link", "laser", RNG.uniform(-1, 1, 3), Rotation.random(random_state=1).as_quat()),
          ("laser", "camera", RNG.uniform(-1, 1, 3), Rotation.random(random_state=2).as_quat())]
DYNAMIC = [("map", "odom", RNG.uniform(-5, 5, 3), Rotation.random(random_state=3).as_quat()),
           ("odom", "base_link", RNG.uniform(-5, 5, 3), Rotation.random(random_state=4).as_quat())]
MOVED = ("odom", "base_link", RNG.uniform(-5, 5, 3), Rotation.random(random_state=5).as_quat())
BAD = ("odom", "wheel", np.array([0.1, math.nan, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
IMU = ("base_link", "imu", RNG.uniform(-1, 1, 3), Rotation.random(random_state=6).as_quat())


def message(edges, stamp_ns: int):
    msg = tf2_msgs.TFMessage()
    for parent, child, t, q in edges:
        tf = TransformStamped()
        tf.header.frame_id, tf.child_frame_id = parent, child
        tf.header.stamp.sec, tf.header.stamp.nanosec = divmod(stamp_ns, SECOND)
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = map(float, t)
        r = tf.transform.rotation
        r.x, r.y, r.z, r.w = map(float, q)
        msg.transforms.append(tf)
    return msg


def matrix(t, q) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix()
    m[:3, 3] = t
    return m


def chain(*edges) -> np.ndarray:
    out = np.eye(4)
    for _, _, t, q in edges:
        out = out @ matrix(t, q)
    return out


def looked_up(tree: TransformTree, target: str, source: str) -> np.ndarray | None:
    try:
        found = tree.lookup(target, source)
    except FrameError:
        return None
    return matrix(found.translation, found.rotation)


def test_the_listener_gets_late_static_and_dynamic_transforms_and_refuses_a_nan_one():
    context = rclpy.Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    nodes = []
    try:
        talker = Node("tf_talker", context=context)
        nodes.append(talker)
        static_pub = talker.create_publisher(tf2_msgs.TFMessage, "/tf_static", TF_STATIC_QOS)
        tf_pub = talker.create_publisher(tf2_msgs.TFMessage, "/tf", TF_QOS)
        static_pub.publish(message(STATIC, 0))  # once, before the listener exists
        listener_node = Node("tf_listener", context=context)
        nodes.append(listener_node)
        tree = TransformTree()
        listener = TransformListener(listener_node, tree)
        executor.add_node(talker)
        executor.add_node(listener_node)

        def spin_until(done) -> bool:
            deadline = time.monotonic() + TIMEOUT_S
            while not done():
                if time.monotonic() > deadline:
                    return False
                executor.spin_once(timeout_sec=0.02)
            return True

        assert spin_until(lambda: looked_up(tree, "base_link", "camera") is not None), "no /tf_static"
        np.testing.assert_allclose(looked_up(tree, "base_link", "camera"), chain(*STATIC), atol=1e-12)

        def dynamic_arrived() -> bool:  # /tf is volatile: published until the listener has it
            tf_pub.publish(message(DYNAMIC, DYNAMIC_NS))
            return looked_up(tree, "map", "camera") is not None

        assert spin_until(dynamic_arrived), "no /tf"
        np.testing.assert_allclose(looked_up(tree, "map", "camera"), chain(*DYNAMIC, *STATIC), atol=1e-12)
        np.testing.assert_allclose(looked_up(tree, "camera", "map"), np.linalg.inv(chain(*DYNAMIC, *STATIC)),
                                   atol=1e-12)

        tf_pub.publish(message([MOVED, BAD, IMU], MOVED_NS))  # once: the good ones kept, the NaN one counted
        assert spin_until(lambda: looked_up(tree, "map", "imu") is not None), "no /tf with the NaN"
        np.testing.assert_allclose(looked_up(tree, "map", "imu"), chain(DYNAMIC[0], MOVED, IMU), atol=1e-12)
        np.testing.assert_allclose(looked_up(tree, "odom", "laser"), chain(MOVED, STATIC[0]), atol=1e-12)
        assert looked_up(tree, "odom", "wheel") is None
        assert dict(listener.refused) == {"non_finite": 1}
        # the stamps are the headers': each dynamic edge's age counts, the static ones' never
        now_ns = MOVED_NS + 400_000_000
        tree.lookup("odom", "camera", now_ns=now_ns, max_age_s=0.5)
        with pytest.raises(FrameError, match="'odom' -> 'base_link'"):
            tree.lookup("odom", "camera", now_ns=now_ns + 200_000_000, max_age_s=0.5)
        tree.lookup("map", "camera", now_ns=now_ns, max_age_s=1.7)  # map -> odom: 1.65 s old
        with pytest.raises(FrameError, match="'map' -> 'odom'"):
            tree.lookup("map", "camera", now_ns=now_ns, max_age_s=1.6)
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        context.try_shutdown()
