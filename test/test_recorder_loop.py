"""The recorder's own wait loop (`RecorderNode.spin`): the node's other entities still run, sim-time log times.

The recording subscriptions are taken by the recorder's loop, not by an executor; its timers (topic
discovery), parameter services and the time source's /clock subscription must still be served while it
records, and the CPU benchmark beside bare readers must count every message (it fails on a lost one).
"""

from __future__ import annotations

import time

import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from harness import Harness
from recording_helpers import expected_values, values_of, wait_for
from robotino_geom_mpc.bench.recorder_cpu import READERS, bench_recorder_cpu
from robotino_geom_mpc.recording.bag_reader import BagReader

pytestmark = pytest.mark.ros


def test_parameter_service_and_discovery_run_while_recording(procs, tmp_path):
    out = tmp_path / "bag"
    rec = procs.recorder(out, "topics:=[stream]", "compression:=lz4")
    # the topic appears after the recorder started: only its discovery timer can subscribe it
    pub = procs.publisher([{"topic": "stream", "kind": "float64_array", "rate_hz": 500.0, "count": 2500}])
    wait_for(lambda: "recording /stream " in rec.log_path.read_text(), 30.0, "the recorder to subscribe /stream")
    with Harness("recorder_loop_probe") as harness:
        assert harness.get_parameters("recorder", ["compression", "flush_period_s"]) == ["lz4", 0.5]
        assert pub.poll() is None, "the parameters should have been answered while the recorder records"
    sent = procs.published(pub)["stream"]
    assert procs.stop(rec) == 0
    got = [values_of("float64_array", msg) for _, msg in BagReader(out).decoded(["/stream"])]
    assert got == [expected_values("float64_array", i) for i in range(sent)]


def test_sim_time_log_time_is_the_clock_at_reception(procs, tmp_path):
    out = tmp_path / "bag"
    rec = procs.recorder(out, "topics:=[stream]", "use_sim_time:=true")
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    clock_ns = [5_000_000_000 + k * 10_000_000 for k in range(40)]
    with Harness("recorder_loop_clock") as harness:
        clock = harness.node.create_publisher(Clock, "/clock", reliable)
        stream = harness.node.create_publisher(Float64MultiArray, "stream", reliable)
        assert harness.spin_until(lambda: stream.get_subscription_count() > 0 and clock.get_subscription_count() > 0,
                                  30.0), "the recorder did not subscribe /stream and /clock"
        # the first clock before the stream starts: the recorder's time source is still settling after its start
        # (a loaded CI host logged the first sample at time 0, no clock yet, with only 0.05 s for it)
        clock.publish(Clock(clock=_time(clock_ns[0])))
        assert clock.wait_for_all_acked()
        time.sleep(0.5)
        for k, ns in enumerate(clock_ns):
            clock.publish(Clock(clock=_time(ns)))
            time.sleep(0.05)  # the recorder's time source takes it before the next message
            stream.publish(Float64MultiArray(data=list(expected_values("float64_array", k))))
            time.sleep(0.05)
        assert stream.wait_for_all_acked()
    assert procs.stop(rec) == 0
    recorded = list(BagReader(out).decoded(["/stream"]))
    assert [values_of("float64_array", msg) for _, msg in recorded] == [
        expected_values("float64_array", k) for k in range(len(clock_ns))]
    for k, (message, _) in enumerate(recorded):
        # the ROS time of the recorder: the clock sent just before (or, after a stall, the one before it)
        assert clock_ns[max(k - 1, 0)] <= message.log_time_ns <= clock_ns[k], (k, message.log_time_ns)


def _time(ns: int):
    """A builtin_interfaces/Time of `ns` nanoseconds."""
    from builtin_interfaces.msg import Time

    sec, nanosec = divmod(ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def test_cpu_benchmark_counts_every_message_of_every_reader():
    figures = bench_recorder_cpu(ticks=150, rate_hz=300.0)
    for name in READERS:
        assert figures[f"{name}_cpu_us_per_message"] > 0
    assert figures["recorder_over_take_executor"] == pytest.approx(
        figures["recorder_cpu_us_per_message"] / figures["take_executor_cpu_us_per_message"])
