"""A rosbag2 (MCAP) reader that survives damage, and the one line that tells how damaged a bag is.

The reader walks the file record by record instead of trusting the summary:
a truncated file (no footer, e.g. after SIGKILL) or a corrupt chunk yields
what can be read, and `BagReader.problems` says what was wrong. rosbags'
reader and mcap's readers are not used for this: both stop at the first
defect (rosbags refuses a file without footer; mcap's stream reader raises at
a corrupt chunk and drops the records after it).
"""

from __future__ import annotations

import copy

import io
import os
import struct
from pathlib import Path
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Iterable, Iterator, cast

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema, Statistics
from mcap.stream_reader import get_chunk_data_stream
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos

from robotino_geom_mpc.recording.bagfile import MCAP_MAGIC, BagError, BagMessage, TopicInfo
from robotino_geom_mpc.recording.definitions import message_class

if TYPE_CHECKING:
    from rosbags.rosbag2.metadata import QosDict

__all__ = ["BagReader", "damage_report"]

# libyaml's safe loader where PyYAML has it (the same documents, a tenth of the time: a bag's metadata.yaml
# lists every topic's QoS, 0.1-0.3 s with the pure-Python loader)
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_RECORD_READERS: dict[int, Callable[[ReadDataStream], Any]] = {
    Opcode.HEADER: Header.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read,
    Opcode.METADATA: Metadata.read,
    Opcode.STATISTICS: Statistics.read,
}


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
            doc = yaml.load(meta_path.read_text(), Loader=_SAFE_LOADER)
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


_MESSAGE_HEADER = struct.Struct("<HIQQ")  # a Message record's channel id, sequence, log time, publish time


def _chunk_records(chunk: Chunk) -> list[Any]:
    """The schemas, channels and messages of a chunk (decompressed, its CRC checked; other records skipped).

    mcap's `breakup_chunk` reads a message's fields one stream call each; here one unpack: a 20 s run's
    22 000 messages in a sixth of the time. ValueError (or struct.error) for a record past the chunk's end.
    """
    stream, length = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(length)
    records: list[Any] = []
    pos = 0
    while pos < length:
        opcode, start = data[pos], pos + 9
        end = start + int.from_bytes(data[pos + 1 : start], "little")
        if end > length:
            raise ValueError(f"a record at byte {pos} of the chunk runs past its end ({length} bytes)")
        if opcode == Opcode.MESSAGE:
            if end - start < _MESSAGE_HEADER.size:
                raise ValueError(f"a message record at byte {pos} of the chunk is shorter than its header")
            channel_id, sequence, log_time, publish_time = _MESSAGE_HEADER.unpack_from(data, start)
            body = start + _MESSAGE_HEADER.size
            records.append(Message(channel_id=channel_id, log_time=log_time, data=data[body:end],
                                   publish_time=publish_time, sequence=sequence))
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            records.append(_read_record(opcode, data[start:end]))
        pos = end
    return records


def _read_record(opcode: int, body: bytes) -> Any:
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, len(body))
    reader = _RECORD_READERS.get(opcode)
    return reader(stream) if reader else None


def _qos(profiles: list[dict[str, Any]] | str | None) -> list[dict[str, Any]]:
    """Offered QoS profiles (YAML text, version-9 names or version-8 integers) in the version-9 form."""
    try:
        # (metadata.yaml's own data: parse_qos checks it, its errors caught below)
        return [dict(profile) for profile in dump_qos_v9(parse_qos(cast("list[QosDict] | str", profiles or [])))]
    except (ReaderError, KeyError, TypeError, AttributeError):
        return []


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
    bytes_lost
        Bytes of the files that are in no readable record (0 for an intact bag).

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
        self.bytes_lost = 0
        self._schemas: dict[tuple[int, int], Schema] = {}
        self._channels: dict[tuple[int, int], Channel] = {}
        raw: list[tuple[int, Message]] = []
        for index, file in enumerate(files):
            raw.extend((index, m) for m in self._scan(index, file))
        self.custom_data: dict[str, str] = dict((meta or {}).get("custom_data") or {})
        if meta is None and "rosbag2" in self.metadata:
            try:
                info = yaml.load(self.metadata["rosbag2"]["serialized_metadata"],
                                 Loader=_SAFE_LOADER)["rosbag2_bagfile_information"]
                self.custom_data = dict(info.get("custom_data") or {})
            except (yaml.YAMLError, KeyError, TypeError):
                self.problems.append("the rosbag2 metadata record is not valid YAML")
        qos_by_topic = {}
        for entry in (meta or {}).get("topics_with_message_count") or []:
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
            qos = qos_by_topic.get(channel.topic) or channel.metadata.get("offered_qos_profiles", "")
            self.topics[channel.topic] = TopicInfo(
                channel.topic,
                schema.name if schema else "",
                counts.get(channel.topic, 0),
                _qos(qos),
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
        read = pos  # bytes in readable records
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
                read += end - pos
                if data[end : end + len(MCAP_MAGIC)] != MCAP_MAGIC:
                    self.problems.append(f"{file.name}: the closing MCAP magic after the footer is missing")
                else:
                    read += len(MCAP_MAGIC)
                break
            try:
                record = _read_record(opcode, body)
                if isinstance(record, Chunk):
                    chunks += 1
                    inner = _chunk_records(record)
                else:
                    inner = [record] if record is not None else []
                read += end - pos
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
        self.bytes_lost += size - read
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

    def contents(self) -> str:
        """What the bag holds, in words: messages per topic and the log-time span."""
        counts = ", ".join(f"{t.name}: {t.message_count}" for t in sorted(self.topics.values(), key=lambda t: t.name))
        span = (self._messages[-1].log_time_ns - self._messages[0].log_time_ns) * 1e-9 if self._messages else 0.0
        return f"{self.message_count} messages ({counts}) over {span:.3f} s"

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

    def in_namespace(self, namespace: str) -> BagReader:
        """This recording as one robot of a fleet's (`ros.fleet`) sees it: the topics in `namespace` (``robot1``) and
        the global ones (``/clock``, ``/tf``, ...), not the other robots'; what the report reads of one robot.
        BagError if no topic is in `namespace`.
        """
        prefix = "/" + namespace.strip("/") + "/"
        if not any(name.startswith(prefix) for name in self.topics):
            namespaces = sorted({n.split("/")[1] for n in self.topics if n.count("/") > 1})
            raise BagError(f"{self.path}: no topic in namespace {prefix[:-1]!r} (the recording's: "
                           f"{', '.join(namespaces) or 'none'})")
        view = copy.copy(self)
        view.topics = {n: t for n, t in self.topics.items() if n.startswith(prefix) or n.count("/") == 1}
        view._messages = [m for m in self._messages if m.topic in view.topics]
        return view

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def damage_report(bag: BagReader) -> str | None:
    """One line for a damaged bag: its first defect, what was recovered, and the repair; None if intact."""
    if bag.complete:
        return None
    more = f" (and {len(bag.problems) - 1} more defects)" if len(bag.problems) > 1 else ""
    directory = bag.path if bag.path.is_dir() else bag.path.parent
    return (f"{bag.path} is damaged: {bag.problems[0]}{more}; {bag.bytes_lost} bytes unreadable; recovered "
            f"{bag.contents()}; `robotino-geom-mpc reindex {directory}` rebuilds a finalised bag from it")
