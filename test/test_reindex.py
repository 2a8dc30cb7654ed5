"""`reindex` makes a bag usable after its recorder was SIGKILLed; independent readers check the result.

The recorder runs as a process and is killed mid-run; the publisher notes when it sent each
message (monotonic clock, shared by the processes), which gives the messages published before the
kill. rosbags and mcap-ros2-support read the reindexed bag; the tolerant `BagReader` of the damaged
original gives the counts they must find.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import time

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.reader import read_ros2_messages
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.rosbag2.errors import ReaderError
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

from recording_helpers import PYTHON, build_message, env, expected_values, values_of, wait_for
from robotino_geom_mpc.system.shm import remove_zombie_segments
from robotino_geom_mpc.recording.bag_reader import BagReader, damage_report
from robotino_geom_mpc.recording.bag_writer import BagWriter
from robotino_geom_mpc.recording.bagfile import RUN_METADATA
from robotino_geom_mpc.recording.bag_writer import write_metadata_yaml

pytestmark = pytest.mark.ros

FLUSH_S = 0.2
LATE_S = 0.1  # a flush timer firing late and the delivery to the recorder, on a loaded 2-core machine
RATE_HZ = 200.0
KIND = "float64_array"


def _reindex(path) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "robotino_geom_mpc", "reindex", str(path)], capture_output=True, text=True,
                          env=env(), timeout=120)


def _rosbags_values(path) -> tuple[dict[str, int], list[tuple[int, tuple[float, ...]]]]:
    """Counts per topic and (timestamp, values) of every message, as rosbags reads the bag directory."""
    store = get_typestore(Stores.EMPTY)
    with RosbagsReader(path) as reader:
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        counts = {c.topic: c.msgcount for c in reader.connections}
        got = [(t, values_of(KIND, store.deserialize_cdr(raw, c.msgtype))) for c, t, raw in reader.messages()]
    return counts, got


def test_reindex_after_sigkill_mid_run(procs, tmp_path):
    out = tmp_path / "bag"
    since = time.time()
    rec = procs.recorder(out, "topics:=[stream]", f"flush_period_s:={FLUSH_S}", "scenario:=killed")
    pub = procs.publisher([{"topic": "stream", "kind": KIND, "rate_hz": RATE_HZ, "count": 1200}])
    wait_for(lambda: "recording /stream " in rec.log_path.read_text(), 30.0, "the recorder to subscribe")
    time.sleep(2.5)
    killed_at = time.monotonic()
    assert procs.stop(rec, signal.SIGKILL) == -signal.SIGKILL
    sent = procs.publisher_result(pub)["times"]["stream"]
    remove_zombie_segments(since)  # the killed recorder's Fast DDS segment
    before_kill = sum(t < killed_at for t in sent)
    assert 100 < before_kill < len(sent), "the kill must be mid-run"
    with pytest.raises(FileNotFoundError, match="metadata"):  # the issue: rosbags refuses the killed recorder's bag
        RosbagsReader(out)

    tolerant = BagReader(out)
    assert any("not finalised" in p for p in tolerant.problems)
    recovered = [values_of(KIND, m) for _, m in tolerant.decoded(["/stream"])]
    n = len(recovered)
    assert recovered == [expected_values(KIND, i) for i in range(n)]  # a gap-free prefix
    # everything published up to a flush period (and `LATE_S`) before the kill is on disk, nothing after it
    durable = sum(t < killed_at - FLUSH_S - LATE_S for t in sent)
    print(f"published before the kill {before_kill}, recovered {n}, lost {before_kill - n} "
          f"({(before_kill - n) / RATE_HZ:.3f} s worth)")
    assert durable <= n <= before_kill
    line = damage_report(tolerant)
    assert "\n" not in line and f"recovered {n} messages (/stream: {n})" in line and "reindex" in line

    result = _reindex(out)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and f"recovered {n} messages (/stream: {n})" in result.stdout
    assert (out / "bag_0.mcap.damaged").read_bytes()[:8] == b"\x89MCAP0\r\n"

    counts, got = _rosbags_values(out)
    assert counts == {"/stream": n} == {t.name: t.message_count for t in tolerant.topics.values()}
    assert [v for _, v in got] == recovered
    assert [t for t, _ in got] == [m.log_time_ns for m in tolerant.messages()]
    ros2 = [(m.log_time_ns, m.publish_time_ns, values_of(KIND, m.ros_msg))
            for m in read_ros2_messages(str(out / "bag_0.mcap"))]
    assert ros2 == [(m.log_time_ns, m.publish_time_ns, v) for m, v in zip(tolerant.messages(), recovered)]
    with open(out / "bag_0.mcap", "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == n and summary.chunk_indexes
        stored = {m.name: m.metadata for m in reader.iter_metadata()}
    assert stored[RUN_METADATA]["scenario"] == "killed"
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == n and meta["custom_data"][f"{RUN_METADATA}.scenario"] == "killed"
    assert BagReader(out).problems == []


def _flushed_copy(tmp_path):
    """A bag as a killed writer leaves it: 300 messages written and flushed, no summary; and the intact bag."""
    with BagWriter(tmp_path / "intact", chunk_size=4096) as writer:
        channel = writer.add_topic("/stream", "std_msgs/msg/Float64MultiArray")
        for i in range(300):
            writer.write(channel, 10**9 + i * 10**6, serialize_message(build_message(KIND, i)))
        writer.flush()
        shutil.copytree(tmp_path / "intact", tmp_path / "killed")
        meta = writer.metadata()
    return tmp_path / "killed", meta


def test_rosbags_does_not_open_an_unfinalised_mcap_even_with_metadata_yaml(tmp_path):
    """Why the recorder does not keep metadata.yaml current: rosbags needs the MCAP footer anyway."""
    killed, meta = _flushed_copy(tmp_path)
    write_metadata_yaml(killed, meta)  # what a recorder updating metadata.yaml at each flush would leave
    with pytest.raises(ReaderError, match="magic"):
        RosbagsReader(killed).open()
    assert BagReader(killed).message_count == 300  # the tolerant reader reads it; reindex finalises it
    assert _reindex(killed).returncode == 0
    counts, got = _rosbags_values(killed)
    assert counts == {"/stream": 300} and [v for _, v in got] == [expected_values(KIND, i) for i in range(300)]


def test_reindex_of_an_intact_bag_only_rewrites_metadata_yaml(tmp_path):
    killed, meta = _flushed_copy(tmp_path)
    intact = tmp_path / "intact"
    before = (intact / "intact_0.mcap").read_bytes()
    expected = yaml.safe_load((intact / "metadata.yaml").read_text())
    (intact / "metadata.yaml").unlink()
    result = _reindex(intact)
    assert result.returncode == 0 and "is intact: 300 messages (/stream: 300)" in result.stdout
    assert (intact / "intact_0.mcap").read_bytes() == before and not list(intact.glob("*.damaged"))
    assert yaml.safe_load((intact / "metadata.yaml").read_text()) == expected


@pytest.mark.parametrize("damage", ["cut inside the header", "garbage after the magic", "garbage file", "empty"])
def test_unreadable_mcap_is_a_one_line_error(tmp_path, damage):
    killed, _ = _flushed_copy(tmp_path)
    mcap = killed / "intact_0.mcap"
    data = mcap.read_bytes()
    rng = __import__("random").Random(7)
    garbage = bytes(rng.randrange(256) for _ in range(len(data)))
    mcap.write_bytes({"cut inside the header": data[:20], "garbage after the magic": data[:8] + garbage,
                      "garbage file": garbage, "empty": b""}[damage])
    for verb in (["reindex"], ["report", "--out", str(tmp_path / "r")], ["regress"], ["replay", "--delay", "0"]):
        result = subprocess.run([PYTHON, "-m", "robotino_geom_mpc", verb[0], str(killed), *verb[1:]],
                                capture_output=True, text=True, env=env(), timeout=60)
        assert result.returncode == 2, (verb, result.stderr)
        assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
        assert result.stderr.startswith(f"robotino-geom-mpc {verb[0]}: error: ")
    assert not list(killed.glob("*.damaged"))  # reindex left the file alone
