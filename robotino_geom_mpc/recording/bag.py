"""rosbag2-compatible MCAP bags: a writer that follows rosbag2's conventions and a reader that survives damage.

Layout (what ``ros2 bag record -s mcap`` of ROS 2 Jazzy writes): a directory
``NAME/`` with ``NAME_0.mcap`` and ``metadata.yaml``
(``rosbag2_bagfile_information``, version 9). The MCAP file has profile
``ros2``; one schema per message type (encoding ``ros2msg``, the .msg text
with every dependent definition appended after a line of 80 ``=`` and
``MSG: pkg/Type``, as rosbag2's LocalMessageDefinitionSource does); one
channel per topic (message encoding ``cdr``, metadata ``offered_qos_profiles``
as YAML and ``topic_type_hash``); messages with the receive time as
``log_time`` and the publisher's source time as ``publish_time``. Chunks are
compressed (zstd, else lz4) and `BagWriter.flush` ends the chunk in progress
so that a killed writer leaves readable chunks behind.

The reader walks the file record by record instead of trusting the summary:
a truncated file (no footer, e.g. after SIGKILL) or a corrupt chunk yields
what can be read, and `BagReader.problems` says what was wrong.
"""

from __future__ import annotations

import importlib
import io
import os
import re
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Iterable, Iterator

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema, Statistics
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

__all__ = [
    "BagError",
    "BagWriter",
    "BagReader",
    "BagMessage",
    "TopicInfo",
    "MCAP_MAGIC",
    "METADATA_VERSION",
    "ROS_DISTRO",
    "message_definition",
    "message_class",
    "default_compression",
    "default_bag_name",
    "RUN_METADATA",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
METADATA_VERSION = 9  # rosbag2 Jazzy: QoS policies as lower-case names
ROS_DISTRO = "jazzy"
# MCAP metadata record (and custom_data key prefix) in which the recorder stores the run's parameters
RUN_METADATA = "robotino_geom_mpc"
_SEPARATOR = "=" * 80 + "\n"
_PRIMITIVES = frozenset(
    "bool byte char float32 float64 int8 uint8 int16 uint16 int32 uint32 int64 uint64 string".split()
)
# field types of a .msg, as rosbag2 finds them (a type at the start of a line, optional array suffix)
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")


class BagError(Exception):
    """A bag that cannot be opened or read at all (missing, not MCAP, nothing readable), or a bad write."""


@dataclass(frozen=True)
class TopicInfo:
    """One recorded topic: name, ROS type (``pkg/msg/Type``), count, offered QoS and type hash."""

    name: str
    type: str
    message_count: int
    offered_qos_profiles: list[dict[str, Any]]
    type_description_hash: str
    message_definition: str


@dataclass(frozen=True)
class BagMessage:
    """One serialized message: times in ns (log = receive, publish = source) and the CDR bytes."""

    topic: str
    type: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


def default_compression() -> str:
    """zstd when the `zstandard` package is importable, else lz4."""
    try:
        import zstandard  # noqa: F401
    except ImportError:
        return "lz4"
    return "zstd"


def _split_type(type_name: str) -> tuple[str, str, str]:
    parts = type_name.split("/")
    if len(parts) == 2:
        return parts[0], "msg", parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise BagError(f"message type '{type_name}' is not of the form pkg/msg/Type")


def _share_dir(package: str) -> Path:
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return Path(get_package_share_directory(package))
    except (PackageNotFoundError, LookupError, ValueError):
        raise BagError(f"package '{package}' not found in the ament index (AMENT_PREFIX_PATH)") from None


def message_definition(type_name: str) -> str:
    """The full ``ros2msg`` text of a type with its dependencies, as rosbag2 writes it into a schema.

    Dependencies are found in each .msg text (sorted, depth first, each type
    once) and appended after ``"\\n" + "=" * 80 + "\\nMSG: pkg/Type\\n"``.
    .msg files are read from ``<prefix>/share/<pkg>/msg/<Type>.msg``.

    Raises
    ------
    BagError
        If a .msg file of the type or of a dependency is missing.
    """
    seen: set[str] = set()

    def load(name: str) -> tuple[str, list[str]]:
        package, folder, base = _split_type(name)
        path = _share_dir(package) / folder / f"{base}.msg"
        try:
            text = path.read_text()
        except OSError:
            raise BagError(f"no message definition for '{name}' ({path} missing)") from None
        deps = set()
        for match in _MSG_FIELD_TYPE.finditer(text):
            field_type = match.group(1)
            if field_type in _PRIMITIVES:
                continue
            deps.add(field_type if "/" in field_type else f"{package}/{field_type}")
        return text, sorted(deps)

    def expand(name: str, depth: int) -> str:
        if depth <= 0:
            raise BagError(f"message definition of '{type_name}' nests too deep")
        text, deps = load(name)
        for dep in deps:
            if dep not in seen:
                seen.add(dep)
                text += "\n" + _SEPARATOR + f"MSG: {dep}\n" + expand(dep, depth - 1)
        return text

    return expand(type_name, 50)


def message_class(type_name: str) -> type:
    """The Python class of a ROS message type ``pkg/msg/Type`` (imported from ``pkg.msg``).

    Raises
    ------
    BagError
        If the package or the type cannot be imported.
    """
    package, folder, base = _split_type(type_name)
    try:
        return getattr(importlib.import_module(f"{package}.{folder}"), base)
    except (ImportError, AttributeError):
        raise BagError(f"message type '{type_name}' is not installed (no Python module {package}.{folder})") from None


def _qos_yaml(profiles: list[dict[str, Any]]) -> str:
    return yaml.safe_dump(profiles, sort_keys=False, default_flow_style=False) if profiles else ""


class BagWriter:
    """Write a rosbag2 bag directory with one MCAP file (rosbag2 Jazzy conventions).

    Parameters
    ----------
    path
        The bag directory; it must not exist yet (as with ``ros2 bag record -o``).
    compression
        ``zstd``, ``lz4`` or ``none`` (per-chunk compression inside the MCAP).
    chunk_size
        Bytes of uncompressed messages after which a chunk is closed.

    Notes
    -----
    `flush` closes the chunk in progress and hands it to the OS, so a process
    killed afterwards leaves it readable; the recorder calls it periodically.
    `close` writes the summary (schemas, channels, statistics, chunk and
    message indexes), the footer, a ``rosbag2`` metadata record and
    ``metadata.yaml``.
    """

    def __init__(self, path: str | os.PathLike, compression: str | None = None, chunk_size: int = 512 * 1024) -> None:
        self.path = Path(path)
        compression = compression or default_compression()
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in kinds:
            raise BagError(f"compression must be one of {', '.join(kinds)}, got {compression!r}")
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
            raise BagError(f"chunk_size must be a positive integer, got {chunk_size!r}")
        if self.path.exists():
            raise BagError(f"bag directory {self.path} already exists")
        try:
            self.path.mkdir(parents=True)
        except OSError as exc:
            raise BagError(f"cannot create bag directory {self.path}: {exc.strerror or exc}") from None
        self.file_name = f"{self.path.name}_0.mcap"
        self._stream = open(self.path / self.file_name, "wb")
        self._writer = Writer(self._stream, chunk_size=chunk_size, compression=kinds[compression])
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
    ) -> int:
        """Register a topic (schema once per type, one channel); returns the channel id for `write`."""
        if name in self._by_name:
            raise BagError(f"topic '{name}' is already in the bag")
        if type_name not in self._schemas:
            text = message_definition(type_name)
            self._schemas[type_name] = self._writer.register_schema(type_name, "ros2msg", text.encode())
        profiles = list(offered_qos_profiles or [])
        channel_id = self._writer.register_channel(
            name,
            "cdr",
            self._schemas[type_name],
            {"offered_qos_profiles": _qos_yaml(profiles), "topic_type_hash": type_description_hash},
        )
        self._topics[channel_id] = {
            "name": name,
            "type": type_name,
            "qos": profiles,
            "hash": type_description_hash,
            "count": 0,
        }
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

    def flush(self) -> None:
        """Close the chunk in progress and pass everything written so far to the OS."""
        if not self._closed:
            self._writer.flush()

    @property
    def message_count(self) -> int:
        return sum(t["count"] for t in self._topics.values())

    def metadata(self) -> dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping of metadata.yaml (version 9)."""
        start = self._first_ns or 0
        duration = (self._last_ns - start) if self._first_ns is not None else 0
        count = self.message_count
        return {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": t["name"],
                        "type": t["type"],
                        "serialization_format": "cdr",
                        "offered_qos_profiles": t["qos"],
                        "type_description_hash": t["hash"],
                    },
                    "message_count": t["count"],
                }
                for t in self._topics.values()
            ],
            # compression happens inside the MCAP chunks (storage level), not by rosbag2_compression
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.file_name],
            "files": [
                {
                    "path": self.file_name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
            ],
            "custom_data": dict(self.custom_data) or None,
            "ros_distro": ROS_DISTRO,
        }

    def close(self) -> None:
        """Finish the MCAP (summary, indexes, footer) and write metadata.yaml; idempotent."""
        if self._closed:
            return
        self._closed = True
        text = yaml.safe_dump({"rosbag2_bagfile_information": self.metadata()}, sort_keys=False)
        self._writer.add_metadata("rosbag2", {"serialized_metadata": text, "ros_distro": ROS_DISTRO})
        self._writer.finish()
        self._stream.close()
        (self.path / "metadata.yaml").write_text(text)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _mcap_files(path: Path) -> tuple[list[Path], dict[str, Any] | None]:
    """The .mcap files of a bag directory (from metadata.yaml, else by glob) or a bare .mcap; and the metadata."""
    if not path.exists():
        raise BagError(f"{path}: no such bag directory or file")
    if path.is_file():
        return [path], None
    meta = None
    meta_path = path / "metadata.yaml"
    if meta_path.is_file():
        try:
            doc = yaml.safe_load(meta_path.read_text())
            meta = doc["rosbag2_bagfile_information"]
            files = [path / p for p in meta["relative_file_paths"]]
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise BagError(f"{meta_path}: not a rosbag2 metadata file ({exc.__class__.__name__})") from None
        if meta.get("storage_identifier") != "mcap":
            raise BagError(f"{path}: storage '{meta.get('storage_identifier')}' is not mcap")
    else:
        files = sorted(path.glob("*.mcap"))
        if not files:
            raise BagError(f"{path}: neither metadata.yaml nor an .mcap file in the directory")
    return files, meta


def _read_record(opcode: int, body: bytes) -> Any:
    stream = ReadDataStream(io.BytesIO(body))
    readers = {
        Opcode.HEADER: Header.read,
        Opcode.SCHEMA: Schema.read,
        Opcode.CHANNEL: Channel.read,
        Opcode.CHUNK: Chunk.read,
        Opcode.METADATA: Metadata.read,
        Opcode.STATISTICS: Statistics.read,
    }
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, len(body))
    reader = readers.get(opcode)
    return reader(stream) if reader else None


class BagReader:
    """Read a bag directory (metadata.yaml + .mcap files) or a bare .mcap file, damaged or not.

    Parameters
    ----------
    path
        A rosbag2 bag directory or an .mcap file.

    Attributes
    ----------
    topics
        Topic name -> `TopicInfo` (counts are what could be read).
    metadata
        MCAP metadata records, name -> string map (e.g. ``robotino_geom_mpc``,
        ``rosbag2``).
    custom_data
        metadata.yaml's custom_data (or, without metadata.yaml, the one in the
        ``rosbag2`` metadata record), else {}.
    problems
        One sentence per defect found (truncation, corrupt chunk, count
        mismatch); empty for an intact bag.

    Raises
    ------
    BagError
        If the path does not exist, is not MCAP, or not a single message can be read.

    Notes
    -----
    The whole bag is read into memory when opened; messages come out in log
    time order (file order among equal times).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        files, meta = _mcap_files(self.path)
        self.problems: list[str] = []
        self.metadata: dict[str, dict[str, str]] = {}
        self._schemas: dict[tuple[int, int], Schema] = {}
        self._channels: dict[tuple[int, int], Channel] = {}
        raw: list[tuple[int, Message]] = []
        for index, file in enumerate(files):
            raw.extend((index, m) for m in self._scan(index, file))
        self.custom_data: dict[str, str] = dict((meta or {}).get("custom_data") or {})
        if meta is None and "rosbag2" in self.metadata:
            try:
                info = yaml.safe_load(self.metadata["rosbag2"]["serialized_metadata"])["rosbag2_bagfile_information"]
                self.custom_data = dict(info.get("custom_data") or {})
            except (yaml.YAMLError, KeyError, TypeError):
                self.problems.append("the rosbag2 metadata record is not valid YAML")
        qos_by_topic = {}
        if meta is not None:
            for entry in meta.get("topics_with_message_count") or []:
                tm = entry.get("topic_metadata", {})
                qos_by_topic[tm.get("name")] = tm.get("offered_qos_profiles")
        self._messages: list[BagMessage] = []
        unknown = 0
        counts: dict[str, int] = {}
        for index, msg in raw:
            channel = self._channels.get((index, msg.channel_id))
            if channel is None:
                unknown += 1
                continue
            schema = self._schemas.get((index, channel.schema_id))
            type_name = schema.name if schema is not None else ""
            self._messages.append(
                BagMessage(channel.topic, type_name, msg.log_time, msg.publish_time, msg.sequence, bytes(msg.data))
            )
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        if unknown:
            self.problems.append(f"{unknown} messages belong to channels whose definition was lost; skipped")
        self._messages.sort(key=lambda m: m.log_time_ns)
        self.topics: dict[str, TopicInfo] = {}
        for (index, _), channel in sorted(self._channels.items()):
            if channel.topic in self.topics:
                continue
            schema = self._schemas.get((index, channel.schema_id))
            qos = qos_by_topic.get(channel.topic)
            if qos is None or isinstance(qos, str):
                try:
                    qos = yaml.safe_load(qos or channel.metadata.get("offered_qos_profiles", "")) or []
                except yaml.YAMLError:
                    qos = []
            self.topics[channel.topic] = TopicInfo(
                channel.topic,
                schema.name if schema else "",
                counts.get(channel.topic, 0),
                list(qos),
                channel.metadata.get("topic_type_hash", ""),
                schema.data.decode(errors="replace") if schema else "",
            )
        if not self._messages and self.problems:
            raise BagError(f"{self.path}: no message could be read: {'; '.join(self.problems)}")

    def _scan(self, index: int, file: Path) -> list[Message]:
        """Walk the records of one MCAP file; collect schemas, channels, metadata and messages."""
        try:
            data = file.read_bytes()
        except OSError as exc:
            raise BagError(f"cannot read {file}: {exc.strerror or exc}") from None
        if len(data) < len(MCAP_MAGIC) or data[: len(MCAP_MAGIC)] != MCAP_MAGIC:
            raise BagError(f"{file}: not an MCAP file (the first 8 bytes are not the MCAP magic)")
        messages: list[Message] = []
        statistics: Statistics | None = None
        pos, size, footer = len(MCAP_MAGIC), len(data), False
        chunks = 0
        while pos < size:
            if pos + 9 > size:
                self.problems.append(
                    f"{file.name} is truncated: it ends at byte {size} inside a record header "
                    f"(not finalised; {chunks} complete chunks read)"
                )
                break
            opcode = data[pos]
            length = int.from_bytes(data[pos + 1 : pos + 9], "little")
            end = pos + 9 + length
            if opcode == 0 or 0x10 <= opcode < 0x80:
                self.problems.append(
                    f"{file.name} is corrupt at byte {pos}: invalid record opcode 0x{opcode:02x}; "
                    f"the rest of the file ({size - pos} bytes) cannot be read"
                )
                break
            if end > size:
                self.problems.append(
                    f"{file.name} is truncated: the record at byte {pos} needs {length} bytes but "
                    f"only {size - pos - 9} remain (not finalised; {chunks} complete chunks read)"
                )
                break
            body = data[pos + 9 : end]
            if opcode == Opcode.FOOTER:
                footer = True
                if data[end : end + len(MCAP_MAGIC)] != MCAP_MAGIC:
                    self.problems.append(f"{file.name}: the closing MCAP magic after the footer is missing")
                break
            try:
                record = _read_record(opcode, body)
                if isinstance(record, Chunk):
                    chunks += 1
                    inner = breakup_chunk(record, validate_crc=True)
                else:
                    inner = [record] if record is not None else []
            except Exception as exc:  # noqa: BLE001 - any decoding failure of one record means a corrupt record
                what = "chunk" if opcode == Opcode.CHUNK else f"record (opcode 0x{opcode:02x})"
                self.problems.append(
                    f"{file.name} is corrupt: the {what} at byte {pos} ({length} bytes) cannot be decoded "
                    f"({exc.__class__.__name__}: {exc}); its messages are skipped"
                )
                inner = []
            for item in inner:
                if isinstance(item, Message):
                    messages.append(item)
                elif isinstance(item, Schema):
                    self._schemas[(index, item.id)] = item
                elif isinstance(item, Channel):
                    self._channels[(index, item.id)] = item
                elif isinstance(item, Metadata):
                    self.metadata[item.name] = dict(item.metadata)
                elif isinstance(item, Statistics):
                    statistics = item
            pos = end
        if not footer and not any(file.name in p for p in self.problems):
            self.problems.append(f"{file.name} is truncated: no footer (the recording was not finalised)")
        if statistics is not None and statistics.message_count != len(messages):
            self.problems.append(
                f"{file.name}: {len(messages)} messages read but the summary lists {statistics.message_count}"
            )
        return messages

    @property
    def complete(self) -> bool:
        """True when no defect was found."""
        return not self.problems

    @property
    def message_count(self) -> int:
        return len(self._messages)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """Serialized messages in log time order, optionally only those of `topics`."""
        wanted = None if topics is None else set(topics)
        for msg in self._messages:
            if wanted is None or msg.topic in wanted:
                yield msg

    def decoded(self, topics: Iterable[str] | None = None) -> Iterator[tuple[BagMessage, Any]]:
        """(message, deserialised ROS message) pairs in log time order (rclpy's deserialize_message)."""
        from rclpy.serialization import deserialize_message

        classes: dict[str, type] = {}
        for msg in self.messages(topics):
            cls = classes.get(msg.type) or classes.setdefault(msg.type, message_class(msg.type))
            yield msg, deserialize_message(msg.data, cls)

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def default_bag_name(now: datetime | None = None) -> str:
    """rosbag2's default directory name, ``rosbag2_YYYY_MM_DD-HH_MM_SS``."""
    return (now or datetime.now()).strftime("rosbag2_%Y_%m_%d-%H_%M_%S")

