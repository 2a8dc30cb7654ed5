"""The processes of benchmark `recorder_cpu`: ``python -m robotino_geom_mpc.bench.recorder_load --role ROLE``.

* ``publisher``: per tick of a fixed rate, the messages of one lockstep tick
  of a recorded run (`tick_messages`), reliable keep-all, serialized once and
  published as bytes, after every topic has matched all readers; it samples
  the readers' CPU time (`process_cpu_s`) just before the first tick and,
  after every reader acknowledged every sample, once the readers are idle
  (`SETTLE_S`), and writes them with the count it sent;
* ``take_executor``: raw subscriptions whose callbacks only count, spun by
  ``SingleThreadedExecutor.spin_once``;
* ``take_waitset``: raw takes of every ready sample from one rclpy wait set.

Each reader takes what its readers still hold at SIGINT and writes its count.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

__all__ = ["MODULE", "SETTLE_S", "TAKERS", "main", "process_cpu_s", "tick_messages"]

MODULE = "robotino_geom_mpc.bench.recorder_load"
SETTLE_S = 0.5  # the readers are done when none used more than 5 % of a core for this long
TAKERS = ("take_executor", "take_waitset")


def process_cpu_s(pid: int) -> float:
    """User + system CPU time [s] of process `pid` so far (``/proc/PID/stat``, fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def tick_messages() -> list[tuple[str, Any]]:
    """(topic, message) of one tick, the sizes of a paper-circle run's (724 B odometry ... 12 B /clock)."""
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import PoseStamped, TransformStamped, Twist
    from nav_msgs.msg import Odometry, Path as PathMsg
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    from tf2_msgs.msg import TFMessage
    from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

    odom = Odometry()
    odom.header.frame_id, odom.child_frame_id = "odom", "base_link"
    preview = MultiDOFJointTrajectory(joint_names=["base_link"])
    preview.header.frame_id = "odom"
    preview.points = [MultiDOFJointTrajectoryPoint(velocities=[Twist()]) for _ in range(13)]
    path = PathMsg()
    path.header.frame_id = "odom"
    path.poses = [PoseStamped() for _ in range(4)]
    diagnostics = DiagnosticArray(status=[DiagnosticStatus(
        name="controller", message="ok", hardware_id="robotino",
        values=[KeyValue(key=f"value_{i}", value="0.000000") for i in range(18)])])
    joints = JointState(name=["wheel_0", "wheel_1", "wheel_2"], position=[0.0] * 3, velocity=[0.0] * 3)
    transform = TransformStamped()
    transform.header.frame_id, transform.child_frame_id = "odom", "base_link"
    tf = TFMessage(transforms=[transform, transform, transform])
    three = Float64MultiArray(data=[0.0, 0.0, 0.0])
    return [("/odom", odom), ("/clock", Clock(clock=Time(sec=1))), ("/reference_preview", preview),
            ("/wheel_voltages", three), ("/predicted_path", path), ("/diagnostics", diagnostics),
            ("/ground_truth/odom", odom), ("/tf", tf), ("/joint_states", joints), ("/wheel_currents", three),
            ("/tf", tf)]


def _settled_cpu_s(pids: dict[str, int], limit_s: float = 60.0) -> dict[str, float]:
    """The CPU time [s] of each process once none of them used more than 5 % of a core for `SETTLE_S`."""
    deadline = time.monotonic() + limit_s
    now = {name: process_cpu_s(pid) for name, pid in pids.items()}
    while True:
        time.sleep(SETTLE_S)
        before, now = now, {name: process_cpu_s(pid) for name, pid in pids.items()}
        if all(now[n] - before[n] <= 0.05 * SETTLE_S for n in pids) or time.monotonic() > deadline:
            return now


def _publisher(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message

    from robotino_geom_mpc.ros.qos import wait_acknowledged

    rclpy.init()
    node = rclpy.create_node("recorder_cpu_publisher")
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE, depth=100)
    messages = tick_messages()
    publishers = {topic: node.create_publisher(type(msg), topic, qos) for topic, msg in messages}
    tick = [(publishers[topic], serialize_message(msg)) for topic, msg in messages]
    pids = {name: int(pid) for name, pid in (item.split("=") for item in args.watch.split(","))}
    deadline = time.monotonic() + 60.0
    while any(p.get_subscription_count() < len(pids) for p in publishers.values()):
        if time.monotonic() > deadline:
            raise SystemExit("recorder_cpu publisher: the readers did not all match within 60 s")
        time.sleep(0.05)
    time.sleep(1.0)  # the recorder's first discovery logs and timers
    before = {name: process_cpu_s(pid) for name, pid in pids.items()}
    start = time.monotonic()
    for i in range(args.ticks):
        time.sleep(max(0.0, start + i / args.rate - time.monotonic()))
        for publisher, data in tick:
            publisher.publish(data)
    wait_acknowledged(node, publishers.values(), 120.0)  # in every reader's history (a reader takes them at stop)
    after = _settled_cpu_s(pids)
    report = {"messages": args.ticks * len(tick), "wall_s": time.monotonic() - start,
              "cpu_s": {name: after[name] - before[name] for name in pids}}
    Path(args.report).write_text(json.dumps(report))
    node.destroy_node()
    rclpy.shutdown()
    return 0


def _take_all(handle: Any, msg_type: Any) -> int:
    """Take every sample the reader of subscription `handle` holds; returns the count."""
    count = 0
    while handle.take_message(msg_type, True) is not None:
        count += 1
    return count


def _take(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    from robotino_geom_mpc.system.signals import STOP, stop_on_signals

    stop_on_signals()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"recorder_cpu_{args.role}")
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE, depth=100)
    count: list[int] = [0]

    def on_message(_data: bytes) -> None:
        count[0] += 1

    subs = [node.create_subscription(type(msg), topic, on_message, qos, raw=True)
            for topic, msg in dict(tick_messages()).items()]
    if args.role == "take_executor":
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while not STOP.is_set():
            executor.spin_once(timeout_sec=0.05)
        count[0] += sum(_take_all(s.handle, s.msg_type) for s in subs)  # what the readers still hold
    else:
        wait_set = _rclpy.WaitSet(len(subs), 0, 0, 0, 0, 0, node.context.handle)
        handles = [(s.handle, s.msg_type) for s in subs]
        while not STOP.is_set():
            wait_set.clear_entities()
            for handle, _ in handles:
                wait_set.add_subscription(handle)
            wait_set.wait(50_000_000)
            count[0] += sum(_take_all(handle, msg_type) for handle, msg_type in handles)
        count[0] += sum(_take_all(handle, msg_type) for handle, msg_type in handles)
    Path(args.report).write_text(json.dumps({"count": count[0]}))
    node.destroy_node()
    rclpy.shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    """``--role publisher|take_executor|take_waitset``: one process of benchmark `recorder_cpu`."""
    parser = argparse.ArgumentParser(prog=f"python -m {MODULE}", description=__doc__.splitlines()[0])
    parser.add_argument("--role", choices=("publisher", *TAKERS), required=True)
    parser.add_argument("--report", default="")
    parser.add_argument("--ticks", type=int, default=2000)
    parser.add_argument("--rate", type=float, default=400.0, help="ticks per second")
    parser.add_argument("--watch", default="", help="name=pid,... of the readers (publisher)")
    args = parser.parse_args(argv)
    if args.role == "publisher":
        return _publisher(args)
    return _take(args)


if __name__ == "__main__":
    sys.exit(main())
