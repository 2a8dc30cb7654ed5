"""QoS profiles of the control loop, chosen on purpose.

* `CONTROL_QOS`, the subscriptions of the control loop (odom,
  wheel_voltages, reference_preview): reliable (a lockstep tick must never
  be lost), keep-last with a small depth (the newest sample is what matters;
  a short queue bounds latency but holds the previews of two ticks in
  flight), volatile (old control data is useless to a late joiner).
* `PUBLISH_QOS`, every publisher of the loop (the same plus wheel_currents,
  joint_states, ground_truth/odom, diagnostics, /clock): the same policies
  with a deeper writer history, so a slow reader such as the recorder can
  lag some ticks behind without losing samples (keep-last never blocks the
  loop).
* `LATCHED_QOS` (reference_path): reliable, keep-last 1, transient local, so
  a visualiser or recorder that starts late still gets the whole reference.
* `CLOCK_SUB_QOS`: the trajectory's own /clock subscription, reliable so no
  lockstep tick is missed (the plant's reliable /clock publisher also serves
  the best-effort subscription of rclpy's time source).
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["CONTROL_QOS", "PUBLISH_QOS", "LATCHED_QOS", "CLOCK_SUB_QOS"]

CONTROL_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
PUBLISH_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
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
