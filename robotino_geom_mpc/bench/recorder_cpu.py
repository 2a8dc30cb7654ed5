"""Benchmark ``recorder_cpu``: the recorder's CPU time per message, beside bare rclpy readers of the same messages.

One publisher process (``python -m robotino_geom_mpc.bench.recorder_cpu
--role publisher``) sends, per tick of a fixed rate, what one lockstep tick
of a recorded run carries: 11 messages on 10 topics with the run's types and
sizes (`tick_messages`: two odometries, the reference preview, the predicted
path, voltages, currents, diagnostics, joint states, /clock and two /tf),
reliable keep-all, serialized once and published as bytes. Three readers of
all of them run at the same time, so they see the same machine:

* the recorder node (`recording.recorder_node`, recording these topics);
* ``take_executor``: a bare rclpy node with raw subscriptions whose
  callbacks do nothing, spun by ``SingleThreadedExecutor.spin_once``
  (what the recorder did before it had its own wait loop);
* ``take_waitset``: raw takes from one rclpy wait set, every ready sample of
  every subscription per wake-up: the floor of taking in Python.

The publisher samples each reader's CPU time (user + system, from
``/proc/PID/stat``) just before the first tick and after the last tick has
had `SETTLE_S` to arrive; the difference over the messages sent is the CPU
per message (process start, discovery and closing the bag are outside it).
The readers' counts (the bag's, read back with `BagReader`, and the bare
readers' own) must equal the messages sent: a lost message fails the run.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from robotino_geom_mpc.bench.registry import BenchmarkError, BenchmarkSkipped, benchmark, wait_for_run
from robotino_geom_mpc.ros.processes import NodeGroup, ros_args

__all__ = ["READERS", "SETTLE_S", "TOPICS", "bench_recorder_cpu", "main", "process_cpu_s", "tick_messages"]

MODULE = "robotino_geom_mpc.bench.recorder_cpu"
SETTLE_S = 1.0  # after the last tick, before the second CPU sample
READERS = ("recorder", "take_executor", "take_waitset")
TOPICS = ("/odom", "/ground_truth/odom", "/reference_preview", "/predicted_path", "/wheel_voltages",
          "/wheel_currents", "/diagnostics", "/joint_states", "/clock", "/tf")


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


def _publisher(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message

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
    time.sleep(SETTLE_S)
    after = {name: process_cpu_s(pid) for name, pid in pids.items()}
    report = {"messages": args.ticks * len(tick), "wall_s": time.monotonic() - start,
              "cpu_s": {name: after[name] - before[name] for name in pids}}
    Path(args.report).write_text(json.dumps(report))
    node.destroy_node()
    rclpy.shutdown()
    return 0


def _take_all(handle: Any, msg_type: type) -> int:
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

    from robotino_geom_mpc.ros.signals import STOP, stop_on_signals

    stop_on_signals()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"recorder_cpu_{args.role}")
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE, depth=100)
    count = [0]

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


def bench_recorder_cpu(ticks: int = 2000, rate_hz: float = 400.0, log_dir: Path | None = None) -> dict[str, float]:
    """One run of the publisher and the three `READERS`: CPU per message [us] of each and the recorder's ratios.

    Raises
    ------
    BenchmarkError
        If a process fails or a reader did not get every message.
    """
    from robotino_geom_mpc.recording.bag import BagReader

    with tempfile.TemporaryDirectory(prefix="recorder_cpu_") as tmp, NodeGroup(log_dir=log_dir) as group:
        out = Path(tmp)
        readers = {"recorder": group.start("recorder_node", ros_args(overrides={
            "output": str(out / "bag"), "topics": list(TOPICS)}))}
        for role in READERS[1:]:
            readers[role] = group.start(role, ["--role", role, "--report", str(out / f"{role}.json")], MODULE)
        watch = ",".join(f"{name}={proc.popen.pid}" for name, proc in readers.items())
        publisher = group.start("publisher", ["--role", "publisher", "--ticks", str(ticks), "--rate", str(rate_hz),
                                              "--watch", watch, "--report", str(out / "publisher.json")], MODULE)
        wait_for_run(group, publisher, 120.0 + 2 * ticks / rate_hz, "recorder_cpu publisher")
        group.stop()
        group.check()
        report = json.loads((out / "publisher.json").read_text())
        sent = report["messages"]
        with BagReader(out / "bag") as bag:
            counts = {"recorder": bag.message_count}
        for role in READERS[1:]:
            counts[role] = json.loads((out / f"{role}.json").read_text())["count"]
    lost = {name: sent - count for name, count in counts.items() if count != sent}
    if lost:
        raise BenchmarkError(f"recorder_cpu: of {sent} messages sent, these readers lost some: {lost}")
    us = {name: 1e6 * report["cpu_s"][name] / sent for name in READERS}
    return {"recorder_cpu_us_per_message": us["recorder"],
            "take_executor_cpu_us_per_message": us["take_executor"],
            "take_waitset_cpu_us_per_message": us["take_waitset"],
            "recorder_over_take_executor": us["recorder"] / us["take_executor"],
            "recorder_over_take_waitset": us["recorder"] / us["take_waitset"],
            "recorder_cpu_messages_per_s": sent / report["wall_s"]}


@benchmark("recorder_cpu", "the recorder's CPU per message (10 topics of a run) beside bare rclpy readers")
def _recorder_cpu(quick: bool) -> dict[str, float]:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        raise BenchmarkSkipped("rclpy is not importable") from None
    return bench_recorder_cpu(ticks=600 if quick else 2000)


def main(argv: list[str] | None = None) -> int:
    """``--role publisher|take_executor|take_waitset`` (a process of the run), or no role: run and print the figures."""
    parser = argparse.ArgumentParser(prog=f"python -m {MODULE}", description=__doc__.splitlines()[0])
    parser.add_argument("--role", choices=("publisher", *READERS[1:]))
    parser.add_argument("--report", default="")
    parser.add_argument("--ticks", type=int, default=2000)
    parser.add_argument("--rate", type=float, default=400.0, help="ticks per second")
    parser.add_argument("--watch", default="", help="name=pid,... of the readers (publisher)")
    args = parser.parse_args(argv)
    if args.role == "publisher":
        return _publisher(args)
    if args.role is not None:
        return _take(args)
    figures = bench_recorder_cpu(args.ticks, args.rate)
    print(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
