"""Recorder node over real DDS: nothing lost, independent readers agree, clean and unclean stops.

The recorder and a test publisher run as separate processes (domain of the session, see conftest).
The long test records 100 Hz and 1 kHz for 10 s at the same time; `test_soak` records the whole loop for a minute.
"""

from __future__ import annotations

import pytest
import signal
import time

import yaml
from mcap.reader import make_reader
from mcap_ros2.reader import read_ros2_messages
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

from recording_helpers import TYPES, expected_values, values_of, wait_for
from robotino_geom_mpc.system.shm import remove_zombie_segments
from robotino_geom_mpc.recording.bag_reader import BagReader

pytestmark = pytest.mark.ros


def _recording(bag: BagReader, topic: str, kind: str) -> list[tuple[float, ...]]:
    return [values_of(kind, msg) for _, msg in bag.decoded([topic])]


def _wait_recording(proc, topics: list[str]) -> None:
    wait_for(lambda: all(f"recording {t} " in proc.log_path.read_text() for t in topics), 30.0,
             f"the recorder to subscribe {topics}")


@pytest.mark.slow
def test_nothing_lost_at_100hz_and_1khz_for_10s(procs, tmp_path):
    out = tmp_path / "bag"
    rec = procs.recorder(out)
    spec = [
        {"topic": "slow", "kind": "float64_array", "rate_hz": 100.0, "count": 1000},
        {"topic": "fast", "kind": "float64_array", "rate_hz": 1000.0, "count": 10000},
        {"topic": "reference_path", "kind": "path", "latched": True},
    ]
    pub = procs.publisher(spec)
    published = procs.published(pub, timeout=60.0)
    assert procs.stop(rec) == 0
    bag = BagReader(out)
    assert bag.problems == []
    for item in spec:
        topic = "/" + item["topic"]
        assert bag.topics[topic].message_count == published[item["topic"]]
        assert bag.topics[topic].type == TYPES[item["kind"]]
    # every message, in publication order, with its values
    for item in spec[:2]:
        got = _recording(bag, "/" + item["topic"], item["kind"])
        assert got == [expected_values(item["kind"], i) for i in range(item["count"])]
    assert _recording(bag, "/reference_path", "path") == [expected_values("path", 0)]
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts["/slow"] == 1000 and counts["/fast"] == 10000 and counts["/reference_path"] == 1


def test_independent_readers_decode_the_published_values(procs, tmp_path):
    out = tmp_path / "bag"
    rec = procs.recorder(out, "topics:=[odom, joint_states, wheel_voltages, reference_path]",
                         "scenario:=paper-circle")
    spec = [
        {"topic": "odom", "kind": "odometry", "rate_hz": 200.0, "count": 150},
        {"topic": "joint_states", "kind": "joint_state", "rate_hz": 200.0, "count": 150},
        {"topic": "wheel_voltages", "kind": "float64_array", "rate_hz": 100.0, "count": 75},
        {"topic": "reference_path", "kind": "path", "latched": True},
        {"topic": "not_recorded", "kind": "float64_array", "rate_hz": 100.0, "count": 0},
    ]
    published = procs.published(procs.publisher(spec))
    assert procs.stop(rec) == 0
    kinds = {"/" + s["topic"]: s["kind"] for s in spec[:4]}

    # rosbags: the directory as a rosbag2 bag, types from the stored ros2msg definitions
    store = get_typestore(Stores.EMPTY)
    with RosbagsReader(out) as reader:
        for conn in reader.connections:
            assert conn.msgdef.format.name.lower() == "msg"
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        assert {c.topic: c.msgtype for c in reader.connections} == {t: TYPES[k] for t, k in kinds.items()}
        for conn in reader.connections:  # the stored definition is the one the publisher's type hash was made of
            assert store.hash_rihs01(conn.msgtype) == conn.digest and conn.digest.startswith("RIHS01_")
        assert {c.topic: c.msgcount for c in reader.connections} == {t: published[t[1:]] for t in kinds}
        got: dict[str, list] = {t: [] for t in kinds}
        for conn, _, raw in reader.messages():
            got[conn.topic].append(values_of(kinds[conn.topic], store.deserialize_cdr(raw, conn.msgtype)))
        path_qos = next(c for c in reader.connections if c.topic == "/reference_path").ext.offered_qos_profiles
        assert path_qos[0].durability.name == "TRANSIENT_LOCAL"
    for topic, kind in kinds.items():
        assert got[topic] == [expected_values(kind, i) for i in range(published[topic[1:]])]

    # mcap-ros2-support: the bare .mcap, decoding with its own parser of the schemas
    mcap_file = next(out.glob("*.mcap"))
    got = {t: [] for t in kinds}
    for m in read_ros2_messages(str(mcap_file)):
        assert m.schema.encoding == "ros2msg" and m.channel.message_encoding == "cdr"
        assert m.schema.name == TYPES[kinds[m.channel.topic]]
        got[m.channel.topic].append(values_of(kinds[m.channel.topic], m.ros_msg))
    for topic, kind in kinds.items():
        assert got[topic] == [expected_values(kind, i) for i in range(published[topic[1:]])]

    with open(mcap_file, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert {ci.compression for ci in summary.chunk_indexes} <= {"zstd", "lz4"}
        for channel in summary.channels.values():
            offered = yaml.safe_load(channel.metadata["offered_qos_profiles"])
            assert offered[0]["reliability"] == "reliable"
            assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
        stored = {m.name: m.metadata for m in reader.iter_metadata()}
    assert stored["robotino_geom_mpc"]["scenario"] == "paper-circle"
    assert "rosbag2" in stored
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap" and meta["ros_distro"] == "jazzy"
    assert meta["relative_file_paths"] == [mcap_file.name]
    assert meta["message_count"] == sum(published[t[1:]] for t in kinds)


def test_sigint_mid_run_leaves_a_complete_bag(procs, tmp_path):
    out = tmp_path / "bag"
    rec = procs.recorder(out, "topics:=[stream]")
    pub = procs.publisher([{"topic": "stream", "kind": "float64_array", "rate_hz": 200.0, "count": 4000}])
    _wait_recording(rec, ["/stream"])
    time.sleep(2.0)
    assert procs.stop(rec, signal.SIGINT) == 0
    assert pub.poll() is None, "the publisher should still be running: the stop is mid-run"
    bag = BagReader(out)
    assert bag.problems == []  # footer, summary, statistics all consistent
    got = _recording(bag, "/stream", "float64_array")
    assert 100 < len(got) < 4000
    assert got == [expected_values("float64_array", i) for i in range(len(got))]  # a gap-free prefix
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == len(got)
    with open(next(out.glob("*.mcap")), "rb") as fh:
        assert make_reader(fh).get_summary().statistics.message_count == len(got)


def test_sigkill_leaves_the_written_chunks_readable(procs, tmp_path):
    out = tmp_path / "bag"
    since = time.time()
    rec = procs.recorder(out, "topics:=[stream]", "flush_period_s:=0.2")
    pub = procs.publisher([{"topic": "stream", "kind": "float64_array", "rate_hz": 500.0, "count": 600}])
    procs.published(pub)  # all sent (and the publisher waited 1 s: more than a flush period)
    assert procs.stop(rec, signal.SIGKILL) == -signal.SIGKILL
    remove_zombie_segments(since)  # the killed recorder's Fast DDS segment, left behind
    assert not (out / "metadata.yaml").exists()
    bag = BagReader(out)
    assert any("truncated" in p and "not finalised" in p for p in bag.problems)
    got = _recording(bag, "/stream", "float64_array")
    assert got == [expected_values("float64_array", i) for i in range(600)]
