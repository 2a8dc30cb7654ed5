"""Replay of recordings made by older code: test/data/regress/ holds one per mode, made by `run` of commit
ec8bd99, and two realtime runs of d447d5f under load whose order and times the replay has to take from the
node (a watchdog stop racing an odometry, an odometry the node took stale); its README.md says how each was made.
They are never re-recorded.

Each recording, read by rosbags (a reader independent of the package's), holds the topics the replay reads, with
their types, every message decodable, and the run's parameters in its metadata (read by mcap), so that the replay
does not depend on today's preset. Today's `regress` reproduces each replayed mode's recorded commands to 1e-12:
every recorded answer of the lockstep run, at most one compared tick per recorded command otherwise; and fails on
a copy of the chain recording (the search over its unrecorded readings) whose one twist was changed by 1e-6,
written by the mcap library.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from rosbags.highlevel import AnyReader

from regress_helpers import regress_verb
from robotino_geom_mpc.recording.bagfile import RUN_METADATA

pytestmark = pytest.mark.unit

DATA = Path(__file__).parent / "data" / "regress"
ODOMETRY = {"/odom": "nav_msgs/msg/Odometry", "/reference_preview": "trajectory_msgs/msg/MultiDOFJointTrajectory"}
DIAGNOSTICS = {"/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
# folder -> (the compared command topic, the topics the replay reads: name -> type)
RECORDINGS = {
    "lockstep_demo": ("/wheel_voltages", {**ODOMETRY, **DIAGNOSTICS,
                                          "/wheel_voltages": "std_msgs/msg/Float64MultiArray"}),
    "realtime_wifi_plans": ("/wheel_voltage_plan", {**ODOMETRY, **DIAGNOSTICS,
                                                    "/wheel_voltage_plan": "trajectory_msgs/msg/JointTrajectory",
                                                    "/command_applied": "trajectory_msgs/msg/JointTrajectory"}),
    "realtime_cmd_vel": ("/cmd_vel", {**ODOMETRY, **DIAGNOSTICS, "/cmd_vel": "geometry_msgs/msg/Twist"}),
    # the chain controller of ec8bd99 published no diagnostics: its inputs and its twists
    "realtime_chain": ("/cmd_vel", {**ODOMETRY, "/cmd_vel": "geometry_msgs/msg/Twist"}),
    # d447d5f, realtime runs under load: a watchdog stop that fired as an odometry was on its way; an odometry
    # published late that the node took stale
    "realtime_watchdog": ("/wheel_voltages", {**ODOMETRY, **DIAGNOSTICS,
                                              "/wheel_voltages": "std_msgs/msg/Float64MultiArray"}),
    "realtime_stale_refusal": ("/wheel_voltages", {**ODOMETRY, **DIAGNOSTICS,
                                                   "/wheel_voltages": "std_msgs/msg/Float64MultiArray"}),
}
# the modes today's regress replays: every one (the chain's by `regress_chain`: its parameters from the preset, as
# the recording holds none of the controller's)
REPLAYED = ("lockstep_demo", "realtime_wifi_plans", "realtime_cmd_vel", "realtime_chain", "realtime_watchdog",
            "realtime_stale_refusal")


def _counts(folder: str) -> dict[str, tuple[str, int]]:
    """Per topic of the recording's replay inputs: (type, messages decoded by rosbags)."""
    topics = RECORDINGS[folder][1]
    counts: dict[str, tuple[str, int]] = {}
    with AnyReader([DATA / folder]) as reader:
        connections = [c for c in reader.connections if c.topic in topics]
        for connection, _, raw in reader.messages(connections):
            reader.deserialize(raw, connection.msgtype)
            kind, n = counts.get(connection.topic, (connection.msgtype, 0))
            counts[connection.topic] = (kind, n + 1)
    return counts


@pytest.mark.parametrize("folder", sorted(RECORDINGS))
def test_recording_holds_what_the_replay_reads(folder):
    counts = _counts(folder)
    assert {topic: kind for topic, (kind, _) in counts.items()} == RECORDINGS[folder][1]
    assert all(n > 0 for _, n in counts.values()), counts
    with open(next((DATA / folder).glob("*.mcap")), "rb") as stream:
        metadata = {record.name: record.metadata for record in make_reader(stream).iter_metadata()}
    parameters = json.loads(metadata[RUN_METADATA]["parameters"])
    assert parameters["control.period_s"] > 0


@pytest.mark.parametrize("folder", REPLAYED)
def test_regress_replays_a_recording_of_older_code(folder, capsys, monkeypatch):
    command = RECORDINGS[folder][0]
    recorded = _counts(folder)[command][1]
    status, result = regress_verb(DATA / folder, monkeypatch)
    assert result.command == command.lstrip("/")
    assert 0 < result.compared <= recorded
    if folder == "lockstep_demo":  # lockstep: every tick's answer is compared
        assert result.compared == result.ticks == recorded
    assert result.gap is None and result.max_deviation_v <= 1e-12 and result.passed
    assert status == 0
    assert capsys.readouterr().out.startswith(f"PASS: {result.compared} of {result.ticks} ticks compared")


def test_the_watchdog_recording_holds_a_stop_before_an_odometry_published_earlier():
    """What `realtime_watchdog` pins (its replay above): the node's stale-odometry stop fired (its status's stamp,
    the node's clock) before an odometry published just before that status was, and the node answered that
    odometry with no status (the stop had forgotten the preview); the replay has to take the stop first.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message

    def ns(stamp) -> int:
        return stamp.sec * 1_000_000_000 + stamp.nanosec

    odometry, stops, statuses = [], [], set()
    with open(next((DATA / "realtime_watchdog").glob("*.mcap")), "rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages(topics=["/odom", "/diagnostics"]):
            if channel.topic == "/odom":
                odometry.append((message.publish_time, ns(deserialize_message(message.data, Odometry).header.stamp)))
                continue
            msg = deserialize_message(message.data, DiagnosticArray)
            for status in msg.status:
                if status.message.startswith("watchdog: stale_odom"):
                    stops.append((ns(msg.header.stamp), message.publish_time))
                elif status.message == "tracking":
                    statuses.add(ns(msg.header.stamp))
    raced = [(fired, stamp) for fired, status_publish in stops for publish, stamp in odometry
             if fired < publish < status_publish]
    assert len(raced) == 1 and raced[0][1] not in statuses
    after = sorted(stamp for _, stamp in odometry if stamp > raced[0][1])
    assert after[0] in statuses  # the restart: the next odometry answered


def test_the_stale_refusal_recording_holds_an_odometry_fresh_at_its_publication_and_refused_stale():
    """What `realtime_stale_refusal` pins: an odometry the plant published 44 ms after its stamp (fresh then:
    the odometry timeout is 0.1 s) that the node refused as stale when it took it; the replay has to take it at the
    node's clock, not at its publication.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message

    def ns(stamp) -> int:
        return stamp.sec * 1_000_000_000 + stamp.nanosec

    published, refused = {}, {}
    with open(next((DATA / "realtime_stale_refusal").glob("*.mcap")), "rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages(topics=["/odom", "/diagnostics"]):
            if channel.topic == "/odom":
                published[ns(deserialize_message(message.data, Odometry).header.stamp)] = message.publish_time
                continue
            msg = deserialize_message(message.data, DiagnosticArray)
            if any(status.message.startswith("refused odom (stale)") for status in msg.status):
                refused[ns(msg.header.stamp)] = message.publish_time
    [(stamp, status_publish)] = refused.items()
    assert published[stamp] - stamp < 0.1e9 < status_publish - stamp


@pytest.mark.slow  # the search over the readings: 1-2 s per case
@pytest.mark.parametrize("twist", [10, 80])  # the robot at rest (the reference's start), on the move
def test_regress_fails_on_a_changed_twist_of_the_older_chain_recording(twist, tmp_path, capsys, monkeypatch):
    from geometry_msgs.msg import Twist
    from rclpy.serialization import deserialize_message, serialize_message

    copy = tmp_path / "changed.mcap"
    with open(next((DATA / "realtime_chain").glob("*.mcap")), "rb") as source, open(copy, "wb") as target:
        reader, writer = make_reader(source), Writer(target)
        writer.start()
        summary = reader.get_summary()
        schemas = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        channels = {cid: writer.register_channel(c.topic, c.message_encoding, schemas[c.schema_id], c.metadata)
                    for cid, c in summary.channels.items()}
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        index = -1
        for _, channel, message in reader.iter_messages(log_time_order=True):
            data = message.data
            if channel.topic == "/cmd_vel":
                index += 1
                if index == twist:
                    msg = deserialize_message(data, Twist)
                    msg.linear.x += 1e-6
                    data = serialize_message(msg)
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time, message.sequence)
        writer.finish()
    status, result = regress_verb(copy, monkeypatch)
    assert status == 1 and not result.passed and 0.5e-6 < result.max_deviation_v < 2e-6
    assert capsys.readouterr().out.startswith(f"FAIL: {result.compared} of {result.ticks} ticks compared")
