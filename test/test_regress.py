"""Replay regression on a recording of the real nodes (plant, controller, trajectory in lockstep, recorder).

The recorded odometry and previews through a fresh controller give the recorded voltages to 1e-12;
one voltage perturbed by 1e-9 V in a copy of the bag makes it fail, naming that deviation; a copy
without one tick's odometry or preview is replayed up to that tick, which is named. A realtime
recording (previews out of phase with the odometry) is reproduced to 1e-12 too.
"""

from __future__ import annotations

import json

import pytest
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import MultiDOFJointTrajectory

from recording_helpers import PYTHON, Processes, wait_for
from robotino_geom_mpc.cli import main
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.system.processes import RECORDER_WAIT_FOR
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bag_writer import BagWriter
from robotino_geom_mpc.recording.bagfile import RUN_METADATA
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.recording.report import by_publish_time, controller_diagnostics, stamp_ns

pytestmark = pytest.mark.ros

PARAMS = str(default_params_file())
# what the plant waits for before tick 0: the controller's and the recorder's subscriptions
WAIT_FOR = f"lockstep_wait_for:={json.dumps(list(RECORDER_WAIT_FOR))}"


def _record(tmp, mode: str, plant_args: list[str]):
    """A paper-circle run of the real nodes in `mode`, recorded; returns the bag directory."""
    procs = Processes(tmp)
    bag = tmp / "bag"
    try:
        rec = procs.start("recorder", [PYTHON, "-m", "robotino_geom_mpc.recording.recorder_node", "--ros-args",
                                       "--params-file", PARAMS, "-p", f"output:={bag}", "-p", "scenario:=paper-circle"])
        node_args = ["--ros-args", "--params-file", PARAMS, "-p", f"mode:={mode}"]
        procs.start("trajectory", [PYTHON, "-m", "robotino_geom_mpc.nodes.trajectory_node", *node_args,
                                   "-p", "scenario:=paper-circle"])
        procs.start("controller", [PYTHON, "-m", "robotino_geom_mpc.nodes.controller_node", *node_args])
        plant = procs.start("plant", [PYTHON, "-m", "robotino_sim_node.plant_node", *node_args, *plant_args])
        assert plant.wait(120) == 0, plant.log_path.read_text()
        wait_for(lambda: "recording /wheel_voltages" in rec.log_path.read_text(), 10.0, "the recorder")
        assert Processes.stop(rec) == 0
    finally:
        procs.close()
    return bag


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A 1 s lockstep paper-circle run of the real nodes, recorded."""
    return _record(tmp_path_factory.mktemp("regress"), "lockstep", ["-p", "duration_s:=1.0", "-p", WAIT_FOR])


def test_regression_reproduces_the_recorded_voltages(recording, capsys):
    result = regress_bag(recording)
    assert result.ticks == 100 and result.compared == 100
    assert result.max_deviation_v <= 1e-12 and result.passed
    assert main(["regress", str(recording)]) == 0
    assert "PASS" in capsys.readouterr().out


def test_regression_fails_on_a_perturbed_voltage(recording, tmp_path, capsys):
    source = BagReader(recording)
    copy = tmp_path / "perturbed"
    seen = 0
    with BagWriter(copy) as out:
        out.add_metadata(RUN_METADATA, source.metadata[RUN_METADATA])
        channels = {name: out.add_topic(name, info.type, info.offered_qos_profiles, info.type_description_hash)
                    for name, info in source.topics.items()}
        for m in source.messages():
            data = m.data
            if m.topic == "/wheel_voltages":
                seen += 1
                if seen == 50:
                    msg = deserialize_message(data, Float64MultiArray)
                    msg.data = [msg.data[0], msg.data[1] + 1e-9, msg.data[2]]
                    data = serialize_message(msg)
            out.write(channels[m.topic], m.log_time_ns, data, m.publish_time_ns, m.sequence)
    result = regress_bag(copy)
    assert not result.passed
    assert result.max_deviation_v == pytest.approx(1e-9, rel=1e-3)
    assert result.worst_time_s == pytest.approx(0.49, abs=1e-9)  # the 50th tick, t = 49 Ts
    assert main(["regress", str(copy)]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "1.000e-09 V" in out


def _copy_without(source: BagReader, copy, topic: str, msg_type, stamp_ns: int) -> None:
    """Copy the bag, leaving out the messages of `topic` stamped `stamp_ns` (a recorder that lost them)."""
    with BagWriter(copy) as out:
        out.add_metadata(RUN_METADATA, source.metadata[RUN_METADATA])
        channels = {name: out.add_topic(name, info.type, info.offered_qos_profiles, info.type_description_hash)
                    for name, info in source.topics.items()}
        for m in source.messages():
            if m.topic == topic:
                stamp = deserialize_message(m.data, msg_type).header.stamp
                if stamp.sec * 1_000_000_000 + stamp.nanosec == stamp_ns:
                    continue
            out.write(channels[m.topic], m.log_time_ns, m.data, m.publish_time_ns, m.sequence)


@pytest.mark.parametrize(("topic", "msg_type", "tick"), [("/odom", Odometry, 40),
                                                         ("/reference_preview", MultiDOFJointTrajectory, 60)])
def test_regression_stops_at_a_tick_whose_input_the_recording_lost(recording, tmp_path, capsys, topic, msg_type,
                                                                   tick):
    source = BagReader(recording)
    first = next(deserialize_message(m.data, Odometry).header.stamp for m in source.messages() if m.topic == "/odom")
    period_s = load_params(PARAMS)[1].period_s
    period_ns = round(period_s * 1e9)
    _copy_without(source, tmp_path / "lossy", topic, msg_type, first.sec * 1_000_000_000 + first.nanosec
                  + tick * period_ns)
    result = regress_bag(tmp_path / "lossy")
    # ticks 0 .. tick - 1 replayed and matching; without the stop, the controller's state would diverge there
    assert (result.ticks, result.compared) == (tick, tick) and result.passed
    assert result.gap == topic.lstrip("/") and result.gap_at_s == pytest.approx(tick * period_s, abs=1e-9)
    assert main(["regress", str(tmp_path / "lossy")]) == 0
    assert f"lacks the {topic.lstrip('/')} of the tick at t = {tick * period_s:.3f} s" in capsys.readouterr().out


def test_regression_reproduces_a_realtime_recording(tmp_path):
    """Realtime: each tick used the freshest preview, moved to its stamp; the diagnostics name which one."""
    bag = _record(tmp_path, "realtime", ["-p", "duration_s:=4.0"])
    result = regress_bag(bag)
    assert result.compared >= 50 and result.compared >= result.ticks - 2  # the last answers may miss the bag
    assert result.max_deviation_v <= 1e-12 and result.passed
    period_ns = round(load_params(PARAMS)[1].period_s * 1e9)
    moved = [abs(int(v["preview_stamp_ns"]) - stamp_ns(m.header.stamp)) for _, m in
             by_publish_time(BagReader(bag), "/diagnostics") if (v := controller_diagnostics(m))]
    assert len(moved) >= 50 and sum(0 < d < 2 * period_ns for d in moved) > len(moved) / 2  # out of phase


def test_regression_of_a_truncated_recording_warns_and_reindex_repairs_it(recording, tmp_path, capsys):
    import subprocess

    from recording_helpers import env

    # the recording rewritten in small chunks (the recorder's own may hold the whole 1 s run in one), so that a
    # cut at two thirds of the file falls among the ticks
    copy = tmp_path / "killed"
    source = BagReader(recording)
    with BagWriter(copy, chunk_size=4096) as out:
        out.add_metadata(RUN_METADATA, source.metadata[RUN_METADATA])
        channels = {name: out.add_topic(name, info.type, info.offered_qos_profiles, info.type_description_hash)
                    for name, info in source.topics.items()}
        for m in source.messages():
            out.write(channels[m.topic], m.log_time_ns, m.data, m.publish_time_ns, m.sequence)
    (copy / "metadata.yaml").unlink()
    mcap = next(copy.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 2 // 3])  # a recorder killed before the end (the summary is lost too)
    full = regress_bag(recording)
    assert main(["regress", str(copy)]) == 0
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and "is damaged" in captured.err and "reindex" in captured.err
    partial = regress_bag(copy)
    assert 0 < partial.compared < full.compared and partial.passed
    assert f"PASS: {partial.compared} of" in captured.out
    result = subprocess.run([PYTHON, "-m", "robotino_geom_mpc", "reindex", str(copy)], capture_output=True,
                            text=True, env=env(), timeout=60)
    assert result.returncode == 0, result.stderr
    assert main(["regress", str(copy)]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and f"PASS: {partial.compared} of {partial.ticks} ticks" in captured.out
