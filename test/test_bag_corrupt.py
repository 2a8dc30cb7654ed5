"""Damaged bags: a truncated and a corrupt file give the documented errors; what can be read is read and replayed."""

from __future__ import annotations

import subprocess

import pytest
from mcap.reader import make_reader
from rclpy.serialization import serialize_message

from recording_helpers import PYTHON, build_message, env, values_of
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bag_writer import BagWriter
from robotino_geom_mpc.recording.bagfile import BagError

pytestmark = pytest.mark.ros

COUNT = 600


def _bag(path):
    """600 Float64MultiArray messages 1 ms apart in small chunks (about 12 chunks)."""
    with BagWriter(path, chunk_size=4096) as bag:
        channel = bag.add_topic("/stream", "std_msgs/msg/Float64MultiArray")
        for i in range(COUNT):
            bag.write(channel, 10**9 + i * 10**6, serialize_message(build_message("float64_array", i)))
    mcap = next(path.glob("*.mcap"))
    with open(mcap, "rb") as fh:
        chunks = sorted(make_reader(fh).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) > 5
    return mcap, chunks


def _indices(bag: BagReader) -> list[int]:
    return [int(values_of("float64_array", m)[0]) for _, m in bag.decoded()]


def _replay(path):
    return subprocess.run([PYTHON, "-m", "robotino_geom_mpc", "replay", str(path), "--rate", "20", "--delay", "0"],
                          capture_output=True, text=True, env=env(), timeout=60)


def test_truncated_bag_reads_its_complete_chunks(tmp_path):
    mcap, chunks = _bag(tmp_path / "bag")
    cut = chunks[4].chunk_start_offset + chunks[4].chunk_length // 2  # inside the fifth chunk
    data = mcap.read_bytes()
    mcap.write_bytes(data[:cut])
    bag = BagReader(mcap)  # the bare file
    assert len(bag.problems) == 1
    assert "truncated" in bag.problems[0] and f"record at byte {chunks[4].chunk_start_offset}" in bag.problems[0]
    # exactly the messages of the four complete chunks, in order
    in_complete = sum(1 for i in range(COUNT) if 10**9 + i * 10**6 <= chunks[3].message_end_time)
    assert _indices(bag) == list(range(in_complete))
    result = _replay(mcap)
    assert result.returncode == 1
    assert "warning" in result.stderr and "truncated" in result.stderr
    assert result.stderr.count("\n") == 1
    assert f"recovered {in_complete} messages (/stream: {in_complete})" in result.stderr
    assert f"replayed {in_complete} messages" in result.stdout
    # the bytes of the cut chunk are lost, everything before it is read
    assert bag.bytes_lost == cut - chunks[4].chunk_start_offset


def test_corrupt_chunk_is_skipped_and_named(tmp_path):
    mcap, chunks = _bag(tmp_path / "bag")
    bad = chunks[2]
    data = bytearray(mcap.read_bytes())
    middle = bad.chunk_start_offset + bad.chunk_length // 2
    data[middle : middle + 16] = bytes(16)  # zero out compressed bytes in the third chunk
    mcap.write_bytes(bytes(data))
    bag = BagReader(tmp_path / "bag")
    corrupt = [p for p in bag.problems if "corrupt" in p]
    assert corrupt and f"chunk at byte {bad.chunk_start_offset}" in corrupt[0]
    lost = {i for i in range(COUNT) if bad.message_start_time <= 10**9 + i * 10**6 <= bad.message_end_time}
    assert _indices(bag) == [i for i in range(COUNT) if i not in lost]
    result = _replay(tmp_path / "bag")
    assert result.returncode == 1 and "corrupt" in result.stderr and result.stderr.count("\n") == 1
    assert bag.bytes_lost == bad.chunk_length  # the corrupt chunk record, nothing else
    assert f"replayed {COUNT - len(lost)} messages" in result.stdout


def test_not_an_mcap_file_is_a_one_line_usage_error(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file at all")
    with pytest.raises(BagError, match="not an MCAP file"):
        BagReader(junk)
    result = _replay(junk)
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "not an MCAP file" in result.stderr
    with pytest.raises(BagError, match="no such bag"):
        BagReader(tmp_path / "missing")
