"""A crash-safe rosbag2 (MCAP) writer that follows rosbag2 Jazzy's conventions.

The MCAP file has profile ``ros2``; one schema per message type (encoding
``ros2msg``, see `definitions.message_definition`); one channel per topic
(message encoding ``cdr``, metadata ``offered_qos_profiles`` as YAML and
``topic_type_hash``); messages with the receive time as ``log_time`` and
the publisher's source time as ``publish_time``. Chunks are compressed
(zstd, else lz4) and `BagWriter.flush` ends the chunk in progress so that
a killed writer leaves readable chunks behind (`reindex` finalises them).

rosbags' `rosbag2.Writer` is not used: it has no flush (a chunk is written
at 1 MiB or at close), no ``publish_time`` (it writes the log time twice),
no lz4, names the file ``NAME.mcap`` and writes ``ros_distro: rosbags``.
"""

from __future__ import annotations

import os
import tempfile
from datetime import datetime
from pathlib import Path
from typing import Any

import yaml
from mcap.data_stream import RecordBuilder
from mcap.writer import CompressionType, Writer

from robotino_geom_mpc.recording.bagfile import ROS_DISTRO, RUN_METADATA, BagError, TopicInfo, bag_metadata
from robotino_geom_mpc.recording.definitions import message_definition

__all__ = ["BagWriter", "default_compression", "default_bag_name", "write_metadata_yaml"]


class _SpooledChunkIndexes:
    """The chunk indexes an `mcap.writer.Writer` keeps for the summary, spooled as their serialized records to an
    unnamed temporary file in the bag's directory until `write` puts them into the summary.

    mcap keeps them as objects, ~1.4 kB a chunk (a dict of message index offsets per channel): a recorder that
    closes a chunk every flush period (0.5 s) grew by 1.7 MB per 10 minutes that way; as records in memory they
    still take 160-220 B a chunk, 0.2-0.3 MB per 10 minutes (bench/README.md, the soak). Spooled, the writer's
    memory stays flat however long it records, and the file is byte for byte the same: `Writer.finish` only
    iterates them and calls ``write`` on each, `Writer` only appends.
    """

    def __init__(self, directory: Path) -> None:
        self._file = tempfile.TemporaryFile(dir=directory)

    def append(self, index: Any) -> None:
        builder = RecordBuilder()
        index.write(builder)
        self._file.write(builder.end())

    def __iter__(self):
        yield self  # all at once: ``write`` puts every record into the summary, in order

    def write(self, builder: RecordBuilder) -> None:
        self._file.seek(0)
        builder.write(self._file.read())

    def close(self) -> None:
        self._file.close()


def default_compression() -> str:
    """zstd when the `zstandard` package (the mcap writer's compressor) is importable, else lz4."""
    try:
        import zstandard  # noqa: F401
    except ImportError:
        return "lz4"
    return "zstd"


def default_bag_name(now: datetime | None = None) -> str:
    """rosbag2's default directory name, ``rosbag2_YYYY_MM_DD-HH_MM_SS``."""
    return (now or datetime.now()).strftime("rosbag2_%Y_%m_%d-%H_%M_%S")


def write_metadata_yaml(directory: Path, metadata: dict[str, Any]) -> str:
    """Write ``directory/metadata.yaml`` atomically (temporary file, then rename); returns the text."""
    text = yaml.safe_dump({"rosbag2_bagfile_information": metadata}, sort_keys=False)
    tmp = directory / "metadata.yaml.tmp"
    tmp.write_text(text)
    tmp.replace(directory / "metadata.yaml")
    return text


class BagWriter:
    """Write a rosbag2 bag directory with one MCAP file (rosbag2 Jazzy conventions).

    Parameters
    ----------
    path
        The bag directory; it must not exist yet (as with ``ros2 bag record -o``),
        unless `file_name` is given.
    compression
        ``zstd``, ``lz4`` or ``none`` (per-chunk compression inside the MCAP).
    chunk_size
        Bytes of uncompressed messages after which a chunk is closed.
    file_name
        Write this file into the existing directory `path` (it must not exist);
        default: create `path` and write ``<name of path>_0.mcap``.

    Notes
    -----
    `flush` closes the chunk in progress and hands it to the OS, so a process
    killed afterwards leaves it readable; the recorder calls it periodically.
    `close` writes the summary (schemas, channels, statistics, chunk and
    message indexes), the footer, a ``rosbag2`` metadata record and
    ``metadata.yaml``.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        compression: str | None = None,
        chunk_size: int = 512 * 1024,
        file_name: str | None = None,
    ) -> None:
        self.path = Path(path)
        compression = compression or default_compression()
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in kinds:
            raise BagError(f"compression must be one of {', '.join(kinds)}, got {compression!r}")
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
            raise BagError(f"chunk_size must be a positive integer, got {chunk_size!r}")
        self.file_name = file_name or f"{self.path.name}_0.mcap"
        try:
            if file_name is None:
                if self.path.exists():
                    raise BagError(f"bag directory {self.path} already exists")
                self.path.mkdir(parents=True)
            self._stream = open(self.path / self.file_name, "xb")
        except OSError as exc:
            raise BagError(f"cannot create {self.path / self.file_name}: {exc.strerror or exc}") from None
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=kinds[compression])
        self._spool = None
        if hasattr(self._writer, "_Writer__chunk_indices"):  # mcap 1.x: the summary's chunk indexes, spooled
            self._spool = self._writer._Writer__chunk_indices = _SpooledChunkIndexes(self.path)
        self._writer.start(profile="ros2", library="robotino_geom_mpc (python mcap)")
        self._schemas: dict[str, int] = {}
        self._topics: dict[int, dict[str, Any]] = {}
        self._by_name: dict[str, int] = {}
        self.custom_data: dict[str, str] = {}
        self._first_ns: int | None = None
        self._last_ns = 0
        self._closed = False

    def add_topic(
        self,
        name: str,
        type_name: str,
        offered_qos_profiles: list[dict[str, Any]] | None = None,
        type_description_hash: str = "",
        definition: str | None = None,
    ) -> int:
        """Register a topic (schema once per type, one channel); returns the channel id for `write`.

        `definition` is the schema text (default: `definitions.message_definition` of the type).
        """
        if name in self._by_name:
            raise BagError(f"topic '{name}' is already in the bag")
        if type_name not in self._schemas:
            text = message_definition(type_name) if definition is None else definition
            self._schemas[type_name] = self._writer.register_schema(type_name, "ros2msg", text.encode())
        profiles = list(offered_qos_profiles or [])
        qos_yaml = yaml.safe_dump(profiles, sort_keys=False, default_flow_style=False) if profiles else ""
        channel_id = self._writer.register_channel(
            name, "cdr", self._schemas[type_name],
            {"offered_qos_profiles": qos_yaml, "topic_type_hash": type_description_hash},
        )
        self._topics[channel_id] = {"name": name, "type": type_name, "qos": profiles,
                                    "hash": type_description_hash, "count": 0}
        self._by_name[name] = channel_id
        return channel_id

    def write(
        self, channel_id: int, log_time_ns: int, data: bytes, publish_time_ns: int | None = None, sequence: int = 0
    ) -> None:
        """Append one serialized (CDR) message to the chunk in progress."""
        topic = self._topics.get(channel_id)
        if topic is None:
            raise BagError(f"unknown channel id {channel_id}")
        log_time_ns = int(log_time_ns)
        publish = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        self._writer.add_message(channel_id, log_time_ns, bytes(data), publish, sequence & 0xFFFFFFFF)
        topic["count"] += 1
        self._first_ns = log_time_ns if self._first_ns is None else min(self._first_ns, log_time_ns)
        self._last_ns = max(self._last_ns, log_time_ns)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write an MCAP metadata record (name -> string map) now."""
        self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def store_run_metadata(self, record: dict[str, str]) -> None:
        """The run's record (`RUN_METADATA`): an MCAP metadata record, flushed now, and custom_data entries."""
        self.add_metadata(RUN_METADATA, record)
        self.flush()
        for key, value in record.items():
            self.custom_data[f"{RUN_METADATA}.{key}"] = str(value)

    def flush(self) -> None:
        """Close the chunk in progress and pass everything written so far to the OS."""
        if not self._closed:
            self._writer.flush()

    @property
    def message_count(self) -> int:
        return sum(t["count"] for t in self._topics.values())

    def metadata(self) -> dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping of metadata.yaml (version 9)."""
        topics = [TopicInfo(t["name"], t["type"], t["count"], t["qos"], t["hash"], "") for t in self._topics.values()]
        return bag_metadata(self.file_name, topics, self._first_ns or 0, self._last_ns, self.custom_data)

    def close(self) -> None:
        """Finish the MCAP (summary, indexes, footer) and write metadata.yaml; idempotent."""
        if self._closed:
            return
        self._closed = True
        text = yaml.safe_dump({"rosbag2_bagfile_information": self.metadata()}, sort_keys=False)
        self._writer.add_metadata("rosbag2", {"serialized_metadata": text, "ros_distro": ROS_DISTRO})
        self._writer.finish()
        self._stream.close()
        self._close_spool()
        write_metadata_yaml(self.path, self.metadata())

    def abort(self) -> None:
        """Close the file as it is (no summary, no metadata.yaml), e.g. before removing it."""
        self._closed = True
        self._stream.close()
        self._close_spool()

    def _close_spool(self) -> None:
        if self._spool is not None:
            self._spool.close()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
