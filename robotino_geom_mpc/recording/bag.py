"""rosbag2-compatible MCAP bags: one import for the writer, the damage-tolerant reader and the definitions.

The pieces live by purpose in `bagfile` (error, constants, record types,
metadata.yaml), `definitions` (ros2msg schemas through rosbags' typesys,
rclpy classes), `bag_writer` (crash-safe writer) and `bag_reader`
(damage-tolerant reader, `damage_report`); `reindex` finalises a damaged bag.
"""

from robotino_geom_mpc.recording.bag_reader import BagReader, damage_report
from robotino_geom_mpc.recording.bag_writer import BagWriter, default_bag_name, default_compression
from robotino_geom_mpc.recording.bagfile import (
    MCAP_MAGIC,
    METADATA_VERSION,
    ROS_DISTRO,
    RUN_METADATA,
    BagError,
    BagMessage,
    TopicInfo,
)
from robotino_geom_mpc.recording.definitions import message_class, message_definition

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
    "damage_report",
    "RUN_METADATA",
]
