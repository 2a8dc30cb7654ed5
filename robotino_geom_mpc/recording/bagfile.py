"""What a rosbag2 bag of this package is made of: its error, constants, record types and metadata.yaml.

Layout (what ``ros2 bag record -s mcap`` of ROS 2 Jazzy writes): a directory
``NAME/`` with ``NAME_0.mcap`` and ``metadata.yaml``
(``rosbag2_bagfile_information``, version 9). Shared by `bag_writer`,
`bag_reader` and `reindex`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from robotino_geom_mpc.errors import RobotinoError

__all__ = [
    "BagError",
    "TopicInfo",
    "BagMessage",
    "MCAP_MAGIC",
    "METADATA_VERSION",
    "ROS_DISTRO",
    "RUN_METADATA",
    "bag_metadata",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
METADATA_VERSION = 9  # rosbag2 Jazzy: QoS policies as lower-case names
ROS_DISTRO = "jazzy"
# MCAP metadata record (and custom_data key prefix) in which the recorder stores the run's parameters
RUN_METADATA = "robotino_geom_mpc"


class BagError(RobotinoError):
    """A bag that cannot be opened or read at all (missing, not MCAP, nothing readable), or a bad write."""


@dataclass(frozen=True)
class TopicInfo:
    """One recorded topic: name, ROS type (``pkg/msg/Type``), count, offered QoS, type hash and definition."""

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


def bag_metadata(
    file_name: str,
    topics: Iterable[TopicInfo],
    start_ns: int,
    end_ns: int,
    custom_data: dict[str, str] | None = None,
) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of a one-file bag (version 9, as rosbag2 Jazzy writes it).

    rosbags writes the same mapping only inside its own `Writer.close` (with
    ``ros_distro: rosbags`` and its own MCAP writer), so it is built here.
    `start_ns` and `end_ns` are the first and last log times (ignored without messages).
    """
    topics = list(topics)
    count = sum(t.message_count for t in topics)
    start, duration = (start_ns, end_ns - start_ns) if count else (0, 0)
    return {
        "version": METADATA_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": t.name,
                    "type": t.type,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": t.offered_qos_profiles,
                    "type_description_hash": t.type_description_hash,
                },
                "message_count": t.message_count,
            }
            for t in topics
        ],
        # compression happens inside the MCAP chunks (storage level), not by rosbag2_compression
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [file_name],
        "files": [
            {
                "path": file_name,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
                "message_count": count,
            }
        ],
        "custom_data": dict(custom_data or {}) or None,
        "ros_distro": ROS_DISTRO,
    }
