"""`robotino-geom-mpc replay` over real DDS: order, relative timing (scaled by --rate) and /clock.

Documented jitter: a message is sent within `JITTER_S` of its due time relative to the first
message (the replayer sleeps to each due time; the margin covers its wake-up on a loaded 2-core
machine). Sending times are the DDS source timestamps the subscriber receives. Each topic keeps
its recorded order; across topics, messages closer in time than the jitter may arrive swapped
(separate DDS readers).
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from recording_helpers import PYTHON, build_message, values_of
from robotino_geom_mpc.recording.bag_writer import BagWriter
from rclpy.serialization import serialize_message

pytestmark = pytest.mark.ros

JITTER_S = 0.03


class Listener:
    """A node in the test process that notes every message with the time the replay sent it.

    The time is the DDS source timestamp (the sender's system clock, in s), so the
    test measures the replay's timing and not this process's scheduling.
    """

    def __init__(self, topics: dict[str, type]) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("replay_listener", context=self.context)
        self.got: list[tuple[str, float, object]] = []
        self.lock = threading.Lock()
        for topic, cls in topics.items():
            self.node.create_subscription(cls, topic, self._cb(topic), QoSProfile(depth=1000))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.running = True
        self.thread.start()

    def _cb(self, topic):
        def cb(msg, info):
            with self.lock:
                self.got.append((topic, info["source_timestamp"] * 1e-9, msg))

        return cb

    def _spin(self) -> None:
        while self.running and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.running = False
        self.thread.join(5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def _make_bag(path):
    """Two topics with irregular gaps over about 1.2 s; log times start at 1000 s."""
    rng = np.random.default_rng(3)
    gaps = rng.uniform(0.002, 0.06, size=40)
    times = 1000.0 + np.concatenate(([0.0], np.cumsum(gaps)))
    order = []
    with BagWriter(path) as bag:
        a = bag.add_topic("/a", "std_msgs/msg/Float64MultiArray")
        b = bag.add_topic("/b", "sensor_msgs/msg/JointState")
        for i, t in enumerate(times):
            topic, channel, kind = ("/a", a, "float64_array") if i % 3 else ("/b", b, "joint_state")
            bag.write(channel, int(round(t * 1e9)), serialize_message(build_message(kind, i)))
            order.append((topic, i, int(round(t * 1e9))))
    return order


def _run_replay(procs, bag, *args):
    argv = [PYTHON, "-m", "robotino_geom_mpc", "replay", str(bag), "--delay", "1.0", "--wait-for-subscribers"]
    return procs.start("replay", argv + list(args))


@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_replay_keeps_order_and_relative_timing(procs, tmp_path, rate):
    order = _make_bag(tmp_path / "bag")
    listener = Listener({"/a": Float64MultiArray, "/b": JointState})
    try:
        proc = _run_replay(procs, tmp_path / "bag", "--rate", str(rate))
        assert proc.wait(60) == 0, proc.log_path.read_text()
        time.sleep(0.3)
    finally:
        listener.close()
    got = [(t, int(values_of("float64_array" if t == "/a" else "joint_state", m)[0]), a) for t, a, m in listener.got]
    for topic in ("/a", "/b"):  # each topic in its recorded order, nothing lost
        assert [i for t, i, _ in got if t == topic] == [i for t, i, _ in order if t == topic]
    # across topics: each message at its recorded time / rate after the start of the replay, within the
    # jitter (which also bounds how far the order across two topics can differ: closer messages may swap)
    arrival = np.array([a for _, _, a in sorted(got, key=lambda g: g[1])])
    due = (np.array([ns for _, _, ns in order]) - order[0][2]) * 1e-9 / rate
    start = np.median(arrival - due)  # the wall time the replay started at, as the subscriber saw it
    assert np.max(np.abs(arrival - due - start)) < JITTER_S


def test_replay_clock_follows_the_recorded_time(procs, tmp_path):
    order = _make_bag(tmp_path / "bag")
    listener = Listener({"/a": Float64MultiArray, "/clock": Clock})
    try:
        proc = _run_replay(procs, tmp_path / "bag", "--clock", "--topics", "a")
        assert proc.wait(60) == 0, proc.log_path.read_text()
        time.sleep(0.3)
    finally:
        listener.close()
    clocks = [m.clock.sec * 10**9 + m.clock.nanosec for t, _, m in listener.got if t == "/clock"]
    data = [(a, m) for t, a, m in listener.got if t == "/a"]
    wanted = [ns for t, _, ns in order if t == "/a"]
    assert clocks == wanted  # one /clock per replayed message, carrying its recorded time, in order
    assert len(data) == len(wanted)
    # the recorded time advances with the wall time of the replay: each /clock sent within the jitter of its due
    # time after the replay's start (as in the test above, the median offset: not one message's, which a late
    # first message would shift every other one by)
    clock_arrival = np.array([a for t, a, _ in listener.got if t == "/clock"])
    late = clock_arrival - (np.array(wanted) - wanted[0]) * 1e-9
    assert np.max(np.abs(late - np.median(late))) < JITTER_S


def test_replay_of_an_unknown_topic_is_a_usage_error(procs, tmp_path):
    _make_bag(tmp_path / "bag")
    proc = _run_replay(procs, tmp_path / "bag", "--topics", "nope")
    assert proc.wait(60) == 2
    err = proc.log_path.read_text().strip().splitlines()
    assert len(err) == 1 and "topics not in the bag: /nope" in err[0]
