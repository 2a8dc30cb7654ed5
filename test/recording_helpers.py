"""Helpers of the recording tests: a test publisher process, the recorder process, their clean-up.

Run as a script, this module is the test publisher: ``python recording_helpers.py SPEC_JSON`` with SPEC
a list of ``{"topic", "type", "rate_hz", "count", "latched"}``. Latched topics are published once at
start (transient local); the others wait for a subscriber, then publish ``count`` messages at
``rate_hz`` (message i carries `expected_values(type, i)`). It prints ``{"published": {topic: n}, "times":
{topic: [t_0, ...]}}`` with the time.monotonic() (CLOCK_MONOTONIC, shared by the processes of the machine)
just before each publish call.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

PYTHON = sys.executable
HERE = Path(__file__).resolve().parent

TYPES = {
    "float64_array": "std_msgs/msg/Float64MultiArray",
    "odometry": "nav_msgs/msg/Odometry",
    "joint_state": "sensor_msgs/msg/JointState",
    "path": "nav_msgs/msg/Path",
}


def expected_values(kind: str, i: int) -> tuple[float, ...]:
    """The numbers message i of a kind carries (what the readers must decode)."""
    if kind == "float64_array":
        return (float(i), i / 7.0, -1.5 * i)
    if kind == "odometry":
        return (i * 1e-3, -i * 2e-3, math.sin(i * 1e-2))
    if kind == "joint_state":
        return (float(i), i + 0.25, i + 0.5)
    if kind == "path":
        return tuple(float(j) * 0.1 for j in range(5))
    raise ValueError(kind)


def build_message(kind: str, i: int):
    """A ROS message of a kind for index i."""
    v = expected_values(kind, i)
    if kind == "float64_array":
        from std_msgs.msg import Float64MultiArray

        return Float64MultiArray(data=list(v))
    if kind == "odometry":
        from nav_msgs.msg import Odometry

        msg = Odometry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(i * 10_000_000, 1_000_000_000)
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.orientation.z = v
        return msg
    if kind == "joint_state":
        from sensor_msgs.msg import JointState

        return JointState(name=["wheel0_joint", "wheel1_joint", "wheel2_joint"], position=list(v))
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path as PathMsg

    msg = PathMsg()
    msg.header.frame_id = "odom"
    for x in v:
        pose = PoseStamped()
        pose.pose.position.x = x
        msg.poses.append(pose)
    return msg


def values_of(kind: str, msg) -> tuple[float, ...]:
    """Numbers of a decoded message (rclpy, rosbags or mcap_ros2 objects alike)."""
    if kind == "float64_array":
        return tuple(float(x) for x in msg.data)
    if kind == "odometry":
        p = msg.pose.pose
        return (p.position.x, p.position.y, p.orientation.z)
    if kind == "joint_state":
        return tuple(float(x) for x in msg.position)
    return tuple(p.pose.position.x for p in msg.poses)


def env() -> dict[str, str]:
    """The environment of child processes (the test session's DDS domain, the venv's ament index)."""
    out = dict(os.environ)
    out.setdefault("AMENT_PREFIX_PATH", sys.prefix)
    out["PYTHONUNBUFFERED"] = "1"
    out["RCUTILS_LOGGING_BUFFERED_STREAM"] = "0"  # log lines reach the log file at once
    return out


class Processes:
    """Child processes of one test; `close` ends those still running (SIGINT, then SIGKILL)."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = Path(log_dir)
        self.procs: list[subprocess.Popen] = []

    def start(self, name: str, argv: list[str]) -> subprocess.Popen:
        log = open(self.log_dir / f"{name}.log", "w")
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env(), cwd=self.log_dir)
        proc.log_path = self.log_dir / f"{name}.log"  # type: ignore[attr-defined]
        self.procs.append(proc)
        return proc

    def recorder(self, out: Path, *params: str, name: str = "recorder") -> subprocess.Popen:
        argv = [PYTHON, "-m", "robotino_geom_mpc.recording.recorder_node", "--ros-args", "-p", f"output:={out}"]
        for p in params:
            argv += ["-p", p]
        return self.start(name, argv)

    def publisher(self, spec: list[dict], name: str = "publisher") -> subprocess.Popen:
        return self.start(name, [PYTHON, str(HERE / "recording_helpers.py"), json.dumps(spec)])

    @staticmethod
    def stop(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout: float = 20.0) -> int:
        if proc.poll() is None:
            proc.send_signal(sig)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise AssertionError(f"process {proc.args[:3]} did not stop within {timeout} s") from None

    @staticmethod
    def published(proc: subprocess.Popen, timeout: float = 120.0) -> dict[str, int]:
        return Processes.publisher_result(proc, timeout)["published"]

    @staticmethod
    def publisher_result(proc: subprocess.Popen, timeout: float = 120.0) -> dict:
        """The publisher's result line: ``published`` counts and ``times`` of each publish call (monotonic)."""
        proc.wait(timeout)
        for line in proc.log_path.read_text().splitlines():  # type: ignore[attr-defined]
            if line.startswith("{"):
                return json.loads(line)
        raise AssertionError(f"publisher printed no result: {proc.log_path.read_text()}")  # type: ignore

    def close(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 10.0
        for proc in self.procs:
            try:
                proc.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()




def wait_for(predicate, timeout: float, what: str) -> None:
    """Poll `predicate` until true, else fail naming `what`."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def _publish(spec: list[dict]) -> None:
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile

    from robotino_geom_mpc.recording.definitions import message_class

    rclpy.init()
    node = rclpy.create_node("test_publisher")
    pubs, streams = {}, []
    for item in spec:
        latched = item.get("latched", False)
        # keep-all: a sample dropped by the transport on a loaded machine is resent when the reader NACKs it
        # (Fast DDS heartbeats every 3 s), which a keep-last history of less than 3 s of messages may not hold
        qos = (QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL) if latched
               else QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1))
        pubs[item["topic"]] = node.create_publisher(message_class(TYPES[item["kind"]]), item["topic"], qos)
        if latched:
            pubs[item["topic"]].publish(build_message(item["kind"], 0))
        else:
            streams.append(item)
    published = {item["topic"]: (1 if item.get("latched") else 0) for item in spec}
    times: dict[str, list[float]] = {item["topic"]: [] for item in streams}
    deadline = time.monotonic() + 30.0
    waiting = [pubs[s["topic"]] for s in streams if s["count"] > 0]  # a count-0 topic may stay unsubscribed
    while any(p.get_subscription_count() < 1 for p in waiting) and time.monotonic() < deadline:
        time.sleep(0.01)
    events = sorted((k / s["rate_hz"], s["topic"], s["kind"], k) for s in streams for k in range(s["count"]))
    start = time.monotonic()
    for due, topic, kind, k in events:
        delay = start + due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        msg = build_message(kind, k)
        times[topic].append(time.monotonic())
        pubs[topic].publish(msg)
        published[topic] += 1
    time.sleep(1.0)  # let reliable delivery finish before the publishers go away
    print(json.dumps({"published": published, "times": times}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    _publish(json.loads(sys.argv[1]))
