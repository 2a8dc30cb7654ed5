"""`BagWriter`'s spooled chunk indexes: the same MCAP bytes as mcap's own list of index objects, and no memory that
grows with the chunks (a recorder closes a chunk every flush period, 0.5 s: 1200 chunks in 10 minutes of a soak).
"""

import pytest
import gc
import tracemalloc
from pathlib import Path

import mcap

from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import Float64MultiArray

from robotino_geom_mpc.recording import bag_writer
from robotino_geom_mpc.recording.bag_writer import BagWriter

pytestmark = pytest.mark.unit

TOPICS = 14  # a run's recorded topics
HASH = get_typestore(Stores.ROS2_JAZZY).hash_rihs01("std_msgs/msg/Float64MultiArray")


class _Objects(list):
    def __init__(self, directory) -> None:
        super().__init__()

    def close(self) -> None:
        pass


def _write(path, chunks: int, per_chunk: int = 5) -> BagWriter:
    writer = BagWriter(path, compression="none")
    channels = [writer.add_topic(f"/t{i}", "std_msgs/msg/Float64MultiArray", [], HASH) for i in range(TOPICS)]
    for k in range(chunks * per_chunk):
        for i, channel in enumerate(channels):
            writer.write(channel, 1_000_000 * k + i, serialize_message(Float64MultiArray(data=[float(k), i])))
        if k % per_chunk == per_chunk - 1:
            writer.flush()
    return writer


def test_spooled_indexes_write_the_same_file_and_every_reader_reads_it(tmp_path, monkeypatch):
    (tmp_path / "spooled").mkdir()
    (tmp_path / "plain").mkdir()
    _write(tmp_path / "spooled" / "bag", 40).close()
    assert sorted(p.name for p in (tmp_path / "spooled" / "bag").iterdir()) == ["bag_0.mcap", "metadata.yaml"]
    monkeypatch.setattr(bag_writer, "_SpooledChunkIndexes", _Objects)  # mcap's own: a list of ChunkIndex objects
    _write(tmp_path / "plain" / "bag", 40).close()
    spooled, plain = (next((tmp_path / name / "bag").glob("*.mcap")).read_bytes() for name in ("spooled", "plain"))
    assert spooled == plain
    with AnyReader([tmp_path / "spooled" / "bag"]) as reader:  # rosbags: through the summary's chunk indexes
        values = [reader.deserialize(raw, conn.msgtype).data.tolist() for conn, _, raw in reader.messages()]
    assert len(values) == 40 * 5 * TOPICS and values[-1] == [199.0, TOPICS - 1]


def test_chunk_indexes_take_no_memory_that_grows_with_the_chunks(tmp_path):
    writer = _write(tmp_path / "warm", 20)
    channels = list(range(1, TOPICS + 1))
    data = serialize_message(Float64MultiArray(data=[1.0, 2.0]))

    def chunks(n: int, start: int) -> None:
        for k in range(start, start + n):
            for channel in channels:
                writer.write(channel, 10**12 + k, data)
            writer.flush()
        gc.collect()

    # the allocations made in the writer's and mcap's code: pytest-xdist's thread allocates meanwhile (work stealing)
    mine = [tracemalloc.Filter(True, bag_writer.__file__), tracemalloc.Filter(True, f"{Path(mcap.__file__).parent}/*")]

    def held() -> int:
        return sum(stat.size for stat in tracemalloc.take_snapshot().filter_traces(mine).statistics("filename"))

    tracemalloc.start()
    chunks(1200, 0)  # 10 minutes of a recorder's chunks: its counters become ints of their final size
    before = held()
    chunks(1200, 1200)  # 10 more
    grown = held() - before
    tracemalloc.stop()
    writer.close()
    # mcap's ChunkIndex objects took ~1450 B a chunk (1.7 MB here), packed records in memory ~160 (190 kB)
    assert grown < 1024
