"""QoS profiles of the control loop, chosen on purpose.

* `CONTROL_QOS`, the subscriptions of the control loop (odom,
  wheel_voltages, reference_preview): reliable (a lockstep tick must never
  be lost), keep-last with a small depth (the newest sample is what matters;
  a short queue bounds latency but holds the previews of two ticks in
  flight), volatile (old control data is useless to a late joiner).
* `LATEST_QOS`, the realtime controller's odometry (not the chain's, which
  reads every sample of the driver's bursts): as `CONTROL_QOS` with depth 1.
  The newest measurement is the only one worth an answer: a controller
  that falls behind (a loaded host, a fleet process) answers the newest
  odometry instead of working through a queue of ones the robot has left
  behind, each answer later than the one before (README: a fleet). The
  replays skip the odometry the node never took (no status of it,
  `recording.replay_inputs.NodeClock.took`).
* `publish_qos(lockstep)`, every publisher of the loop (the same topics
  plus wheel_currents, joint_states, ground_truth/odom, diagnostics,
  /clock), reliable and volatile:

  - realtime: `PUBLISH_QOS`, keep-last 100, so a slow reader such as the
    recorder can lag some ticks behind; a reader further behind loses
    samples, but the loop never waits for an observer (the robot does not).
  - lockstep: `LOCKSTEP_PUBLISH_QOS`, keep-all: a sample leaves the writer's
    history only when every reader has acknowledged it, so nothing is lost
    and the loop runs at most a history ahead of its slowest reader (the
    recorder, whose subscriptions are keep-all too). Fast DDS (2.14, rmw
    defaults) holds up to 5000 unacknowledged samples (resource_limits
    max_samples); a write to a full history blocks for max_blocking_time
    (100 ms) and then fails, which rclpy raises as `RCLError` ("cannot
    publish data"). `publish_acknowledged` turns that into a logged wait.
    A writer's unacknowledged samples die with its process: `ros.spin.run_node`
    calls `wait_acknowledged` before every node exits. A reader that dies
    without leaving the graph (SIGKILL) holds a full history back until DDS
    drops it (the participant's lease, 20 s by default).
* `LATCHED_QOS` (reference_path): reliable, keep-last 1, transient local, so
  a visualiser or recorder that starts late still gets the whole reference.
* `CLOCK_SUB_QOS`: the trajectory's own /clock subscription, reliable so no
  lockstep tick is missed (the plant's reliable /clock publisher also serves
  the best-effort subscription of rclpy's time source).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

from rclpy._rclpy_pybind11 import RCLError
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["CONTROL_QOS", "LATEST_QOS", "PUBLISH_QOS", "LOCKSTEP_PUBLISH_QOS", "LATCHED_QOS", "CLOCK_SUB_QOS",
           "publish_qos", "publish_acknowledged", "wait_acknowledged"]

CONTROL_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
LATEST_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
PUBLISH_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
LOCKSTEP_PUBLISH_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    depth=100,  # ignored by keep-all
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
CLOCK_SUB_QOS = CONTROL_QOS  # /clock drives the lockstep loop like the control topics


def publish_qos(lockstep: bool) -> QoSProfile:
    """The writers' QoS of the loop: keep-all in lockstep (lossless, back-pressure), else keep-last 100."""
    return LOCKSTEP_PUBLISH_QOS if lockstep else PUBLISH_QOS


def publish_acknowledged(node: Node, publisher: Publisher, message: Any) -> None:
    """Publish `message`; if a keep-all writer's history is full, wait (logged) until readers acknowledge.

    A keep-all write that finds the history full of unacknowledged samples fails after the writer's
    max_blocking_time; it is retried, with a throttled warning naming the topic and the time waited,
    until it goes out or the node's context shuts down. Failures of other writers are raised.
    """
    since = time.monotonic()  # the failed write blocked for max_blocking_time: the wait counts from before it
    try:
        publisher.publish(message)
        return
    except RCLError:
        if publisher.qos_profile.history != HistoryPolicy.KEEP_ALL:
            raise
    while node.context.ok():
        warn_throttled(
            node.get_logger(),
            f"{publisher.topic_name}: a subscriber has not acknowledged the writer's history for "
            f"{time.monotonic() - since:.1f} s (a slow reader, e.g. the recorder): waiting",
            2.0,
        )
        try:
            publisher.publish(message)
            return
        except RCLError:
            pass
    raise RCLError(f"{publisher.topic_name}: context shut down while waiting to publish")


def wait_acknowledged(node: Node, publishers: Iterable[Publisher | None], timeout_s: float) -> list[str]:
    """Wait up to `timeout_s` in all until every reader acknowledged every sample; the topics that were not.

    Those are logged as a warning (their samples may not reach a slow reader such as the recorder).
    """
    deadline = time.monotonic() + timeout_s
    late = [pub.topic_name for pub in publishers if pub is not None and not pub.wait_for_all_acked(
        Duration(seconds=max(deadline - time.monotonic(), 0.0)))]
    if late:
        node.get_logger().warn(f"not acknowledged by every subscriber within {timeout_s:g} s: {', '.join(late)}")
    return late
