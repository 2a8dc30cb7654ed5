"""Make a bag whose writer died (SIGKILL, power loss) usable again, as ``ros2 bag reindex`` does.

A killed recorder leaves ``NAME_0.mcap`` without summary and footer and no
metadata.yaml: rosbags refuses it (it needs the footer) and rosbag2 does not
find it. `reindex_bag` reads the readable records with the damage-tolerant
`BagReader`, keeps the damaged file as ``NAME_0.mcap.damaged`` and writes a
finalised ``NAME_0.mcap`` (summary, chunk and message indexes, statistics,
footer; the mcap library's writer through `BagWriter`) with the recovered
schemas (the stored definitions, unchanged), channels (QoS, type hash),
messages (log and publish times, sequence numbers) and metadata records,
then metadata.yaml. An intact file is left as it is and only metadata.yaml
is rebuilt.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bag_writer import BagWriter, write_metadata_yaml
from robotino_geom_mpc.recording.bagfile import RUN_METADATA, BagError, bag_metadata

__all__ = ["ReindexResult", "reindex_bag", "DAMAGED_SUFFIX"]

DAMAGED_SUFFIX = ".damaged"


@dataclass(frozen=True)
class ReindexResult:
    """What `reindex_bag` did.

    Attributes
    ----------
    file
        The bag's MCAP file (finalised now).
    kept
        Where the damaged original was moved (None: the file was intact and is unchanged).
    problems
        The defects the tolerant reader found in the original.
    bytes_lost
        Bytes of the original in no readable record (a cut-off tail, corrupt chunks).
    contents
        What the bag holds now, in words (messages per topic, time span).
    counts
        Messages per topic in the finalised file.
    """

    file: Path
    kept: Path | None
    problems: list[str] = field(default_factory=list)
    bytes_lost: int = 0
    contents: str = ""
    counts: dict[str, int] = field(default_factory=dict)


def _custom_data(bag: BagReader) -> dict[str, str]:
    data = dict(bag.custom_data)
    for key, value in bag.metadata.get(RUN_METADATA, {}).items():
        data.setdefault(f"{RUN_METADATA}.{key}", value)
    return data


def _rewrite(bag: BagReader, directory: Path, file_name: str) -> None:
    """Write the readable content of `bag` as a finalised `file_name` in `directory` (+ metadata.yaml)."""
    writer = BagWriter(directory, file_name=file_name)
    try:
        channels = {
            name: writer.add_topic(name, info.type, info.offered_qos_profiles, info.type_description_hash,
                                   definition=info.message_definition)
            for name, info in bag.topics.items()
        }
        for name, record in bag.metadata.items():
            if name != "rosbag2":  # close() writes the bag's own
                writer.add_metadata(name, record)
        writer.custom_data.update(_custom_data(bag))
        for msg in bag.messages():
            writer.write(channels[msg.topic], msg.log_time_ns, msg.data, msg.publish_time_ns, msg.sequence)
        writer.close()
    except BaseException:
        writer.abort()
        (directory / file_name).unlink(missing_ok=True)
        raise


def reindex_bag(path: str | os.PathLike) -> ReindexResult:
    """Rebuild a bag directory's finalised MCAP file (if damaged) and its metadata.yaml.

    Raises
    ------
    BagError
        If `path` is not a directory with exactly one .mcap file, nothing in it
        can be read (see `BagReader`), or the ``.damaged`` copy exists already.
    """
    directory = Path(path)
    if not directory.is_dir():
        raise BagError(f"{directory}: not a bag directory (reindex takes the directory that holds the .mcap file)")
    files = sorted(directory.glob("*.mcap"))
    if len(files) != 1:
        raise BagError(f"{directory}: reindex needs exactly one .mcap file in the directory, found {len(files)}")
    original = files[0]
    bag = BagReader(original)  # the file alone: a metadata.yaml there may be stale
    if bag.complete:
        topics = bag.topics.values()
        times = [m.log_time_ns for m in bag.messages()]
        write_metadata_yaml(directory, bag_metadata(original.name, topics, min(times, default=0),
                                                    max(times, default=0), _custom_data(bag)))
        return ReindexResult(original, None, [], 0, bag.contents(),
                             {t.name: t.message_count for t in topics})
    kept = original.with_name(original.name + DAMAGED_SUFFIX)
    if kept.exists():
        raise BagError(f"{kept} exists already; move it away before reindexing {directory} again")
    original.rename(kept)
    try:
        _rewrite(bag, directory, original.name)
    except BaseException:
        kept.rename(original)
        raise
    return ReindexResult(original, kept, list(bag.problems), bag.bytes_lost, bag.contents(),
                         {t.name: t.message_count for t in bag.topics.values()})
