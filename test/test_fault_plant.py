"""The plant node as hardware, over DDS with the real node process: clamped drives, refused commands, logged waits.

The truth is a `RobotinoPlant` stepped in the test with the voltages a real H-bridge would apply: each
commanded voltage clamped to +-supply, zero volts from a refused command on.
"""

import json
import math
import time

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from harness import Harness
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.messages import stamp_to_ns
from robotino_geom_mpc.system.processes import NodeGroup, ros_args
from robotino_geom_mpc.ros.qos import PUBLISH_QOS
from robotino_geom_mpc.model.plant import RobotinoPlant
from test_plant_node import _full_state, _offline

pytestmark = pytest.mark.ros

SUPPLY_V = load_params()[0].supply_voltage_v


def _lockstep(tmp, commands: list[list[float]]) -> dict:
    """A lockstep plant of len(commands) ticks, tick k answered with commands[k]; what came back."""
    Ts = load_params()[1].period_s
    with NodeGroup(log_dir=tmp) as group, Harness("fault_test") as h:
        truth = h.collect("ground_truth/odom", Odometry)
        currents = h.collect("wheel_currents", Float64MultiArray)
        h.collect("odom", Odometry)
        h.collect("/clock", Clock)
        pub = h.node.create_publisher(Float64MultiArray, "wheel_voltages", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {
            "mode": "lockstep", "duration_s": len(commands) * Ts, "lockstep_wait_for": ["odom:1", "/clock:1"],
            "lockstep_settle_s": 0.2, "lockstep_resend_s": 5.0}))
        for k, command in enumerate(commands):
            assert h.spin_until(lambda: len(truth) >= k + 1, 30.0), plant.stderr_tail()
            pub.publish(Float64MultiArray(data=command))
            assert h.spin_until(lambda: len(currents) >= k + 1, 10.0), plant.stderr_tail()
        assert group.wait(plant, 10.0) and plant.popen.returncode == 0
        return dict(Ts=Ts, truth=truth, currents=currents, log=plant.stderr_tail(200))


def _compare(run: dict, applied: list[list[float]]) -> None:
    """Currents and poses of the run against a `RobotinoPlant` stepped with `applied`."""
    offline = RobotinoPlant(load_params()[0])
    for k, U in enumerate(applied):
        offline.step(np.array(U, dtype=float), run["Ts"])
        expected = np.copysign(offline.peak_abs_currents, offline.currents)
        np.testing.assert_allclose(run["currents"][k].data, expected, rtol=1e-12, atol=1e-12)
        if k + 1 < len(run["truth"]):
            p = run["truth"][k + 1].pose.pose.position
            np.testing.assert_allclose((p.x, p.y), offline.pose[:2], rtol=0, atol=1e-12)


def test_voltages_beyond_the_supply_are_clamped(tmp_path):
    commands = [[1e9, -1e9, 48.0], [48.0, -48.0, 0.0], [5.0, 1e9, -30.0], [-1e9, 0.0, 0.0]]
    run = _lockstep(tmp_path, commands)
    applied = [[min(max(v, -SUPPLY_V), SUPPLY_V) for v in c] for c in commands]
    _compare(run, applied)
    unclamped = RobotinoPlant(load_params()[0])  # what the plant did before: 1e9 V gave 1.6e8 A
    unclamped.step(np.array(commands[0]), run["Ts"])
    assert max(abs(v) for m in run["currents"] for v in m.data) < 1e-6 * unclamped.peak_abs_currents.max()
    assert "wheel_voltages 1e+09, -1e+09, 48 V beyond the supply +-24 V: applied 24, -24, 24 V" in run["log"]
    assert "4 commands clamped" in run["log"]  # the run's summary line counts them all


def test_a_refused_command_is_zero_volts_at_once_in_lockstep(tmp_path):
    commands = [[10.0, 10.0, 10.0], [10.0, -5.0, 10.0], [math.nan, 1.0, 1.0], [3.0, 3.0]]
    run = _lockstep(tmp_path, commands)
    _compare(run, [commands[0], commands[1], [0.0] * 3, [0.0] * 3])
    assert "2 refused" in run["log"]


@pytest.fixture(scope="module")
def realtime_refusal(tmp_path_factory):
    """A realtime plant (command timeout 5 s): 10 V commands at 100 Hz for 0.3 s, then one NaN command."""
    robot, control = load_params()
    command, duration = [10.0, -10.0, 10.0], 8.0
    report = tmp_path_factory.mktemp("rt_report") / "timing.json"
    with NodeGroup(log_dir=tmp_path_factory.mktemp("rt_refusal")) as group, Harness("rt_refusal") as h:
        truth = h.collect("ground_truth/odom", Odometry)
        joints = h.collect("joint_states", JointState)
        pub = h.node.create_publisher(Float64MultiArray, "wheel_voltages", PUBLISH_QOS)
        started = time.monotonic()
        plant = group.start("plant_node", ros_args(None, {
            "mode": "realtime", "command_timeout_s": 5.0, "duration_s": duration, "timing_report": str(report)}))
        assert h.spin_until(lambda: len(truth) >= 3 and pub.get_subscription_count() >= 1, 30.0), plant.stderr_tail()
        assert time.monotonic() - started < duration - 2.0, "the plant took too long to start for this test"
        for _ in range(30):
            pub.publish(Float64MultiArray(data=command))
            h.spin_for(0.01)
        pub.publish(Float64MultiArray(data=[math.nan, 0.0, 0.0]))
        refused = h.node.get_clock().now().nanoseconds
        h.spin_for(0.6)
        assert group.wait(plant, duration + 10.0) and plant.popen.returncode == 0, plant.stderr_tail()
        log = plant.stderr_tail(100)
    effort = robot.gear_ratio * robot.torque_constant_n_m_per_a
    joint_by_stamp = {stamp_to_ns(m.header.stamp): m for m in joints}
    samples = [(stamp_to_ns(m.header.stamp), _full_state(m, joint_by_stamp[stamp_to_ns(m.header.stamp)], effort))
               for m in truth if stamp_to_ns(m.header.stamp) in joint_by_stamp]
    return dict(robot=robot, Ts=control.period_s, duration=duration, refused=refused, samples=samples, log=log,
                report=json.loads(report.read_text()))


def test_a_refused_command_is_zero_volts_at_once_in_realtime(realtime_refusal):
    run = realtime_refusal
    margin = 0.05  # the receipt of the refusal can lag its send on a loaded host
    after = [(t, s) for t, s in run["samples"] if run["refused"] + margin * 1e9 < t < run["refused"] + 0.5e9]
    assert len(after) >= 20
    (t_a, s_a), (t_b, s_b) = after[0], after[-1]
    assert np.abs(s_a[6:9]).max() > 0.5  # the 10 V command was driving the drives when it was refused
    # long before the 5 s timeout: the offline plant under zero volts (not under the 10 V held before)
    np.testing.assert_allclose(_offline(run["robot"], s_a, [0.0, 0.0, 0.0], (t_b - t_a) * 1e-9), s_b, atol=2e-9)
    assert "refused wheel_voltages with 3 values" in run["log"]


def test_realtime_timing_report(realtime_refusal):
    report, Ts, duration = realtime_refusal["report"], realtime_refusal["Ts"], realtime_refusal["duration"]
    assert report["mode"] == "realtime" and report["refused_commands"] == 1 and report["clamped_commands"] == 0
    # one tick per period over the run, less the periods a late timer skipped on a loaded host
    assert 0.8 * duration / Ts <= report["ticks"] <= duration / Ts + 1
    assert report["simulated_s"] == pytest.approx(duration, abs=2 * Ts)
    assert report["wall_s"] == pytest.approx(duration, abs=2 * Ts)
    assert report["realtime_factor"] == pytest.approx(report["simulated_s"] / report["wall_s"])
    assert 20 <= report["answered"] <= 31  # at most one answer per valid command
    # from the first answer on every tick is answered or missed (the last one may be pending)
    assert report["loop_ticks"] == report["answered"] + report["missed"]
    assert report["ticks"] - report["loop_ticks"] - report["answered"] < report["ticks"]
    assert report["missed"] >= (duration - 2.0 - 0.4) / Ts - 5  # no command after the NaN: every tick missed
    times = [t for t, _ in report["missed_ticks"]]
    assert len(times) == 100 and times == sorted(times) and times[0] > 0  # the first 100, from the first answer
    lat = report["latency_ms"]
    assert 0 < lat["median"] <= lat["p99"] <= lat["max"] + 1e-3
    assert report["tick0_answer_s"] is None and report["first_answer_steady_s"] > 0
    per_tick_ms = 1e3 * report["wall_s"] / report["ticks"]
    assert report["plant_busy_ms_per_tick"] + report["wait_ms_per_tick"] == pytest.approx(per_tick_ms)


def test_a_lockstep_plant_waiting_for_its_loop_says_what_is_missing(tmp_path):
    with NodeGroup(log_dir=tmp_path) as group:
        plant = group.start("plant_node", ros_args(None, {"mode": "lockstep", "duration_s": 1.0}))
        deadline = time.monotonic() + 15.0
        while "waiting" not in plant.stderr_tail(50) and time.monotonic() < deadline:
            time.sleep(0.1)
        log = plant.stderr_tail(50)
    assert "before tick 0 for: wheel_voltages publishers 0/1, odom subscriptions 0/1, /clock subscriptions 0/1" \
        in log, log
