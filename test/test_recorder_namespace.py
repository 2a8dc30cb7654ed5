"""One robot's recording among several: the recorder in a namespace, and `report.find_topic` on its bag."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from recording_helpers import PYTHON
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.report import find_topic

pytestmark = pytest.mark.ros


def test_a_namespaced_recorder_records_its_robot_and_tf_only(procs, tmp_path):
    out = tmp_path / "bag"
    rec = procs.start("recorder", [PYTHON, "-m", "robotino_geom_mpc.recording.recorder_node", "--ros-args",
                                   "-r", "__ns:=/robot1", "-p", f"output:={out}"])
    spec = [
        {"topic": "/robot1/odom", "kind": "float64_array", "rate_hz": 100.0, "count": 150},
        {"topic": "/robot2/odom", "kind": "path", "latched": True},
        {"topic": "/robot10/odom", "kind": "path", "latched": True},
        {"topic": "/tf_static", "kind": "path", "latched": True},
    ]
    published = procs.published(procs.publisher(spec))
    assert procs.stop(rec) == 0
    bag = BagReader(out)
    assert bag.problems == []
    assert set(bag.topics) == {"/robot1/odom", "/tf_static"}
    assert bag.topics["/robot1/odom"].message_count == published["/robot1/odom"] == 150


def _bag(*topics: str) -> SimpleNamespace:
    return SimpleNamespace(path="bag", topics={t: SimpleNamespace(type="nav_msgs/msg/Odometry") for t in topics})


@pytest.mark.parametrize("topics, suffix, expected", [
    (("/odom", "/ground_truth/odom"), "odom", "/odom"),
    (("/robot1/odom", "/robot1/ground_truth/odom"), "odom", "/robot1/odom"),
    (("/robot1/odom", "/robot1/ground_truth/odom"), "ground_truth/odom", "/robot1/ground_truth/odom"),
])
def test_find_topic_takes_the_robots_own_topic_in_a_namespace(topics, suffix, expected):
    assert find_topic(_bag(*topics), suffix, "nav_msgs/msg/Odometry") == expected


def test_find_topic_refuses_two_robots_topics():
    with pytest.raises(BagError, match="several odom topics"):
        find_topic(_bag("/robot1/odom", "/robot2/odom"), "odom", "nav_msgs/msg/Odometry")
    with pytest.raises(BagError, match="no 'odom' topic"):
        find_topic(_bag("/robot1/twist"), "odom", "nav_msgs/msg/Odometry")
