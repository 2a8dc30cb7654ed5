"""The plant simulator refuses to start beside another publisher of its ``odom`` topic (two sources of odometry are
a fault, issue 36): it exits with status 2, names the other publisher's node, and publishes nothing.

The other publisher is a stand-in node in the test process (it never publishes, so whatever the test's own
subscriptions receive came from the plant); one in another namespace does not count.
"""

import subprocess
import sys
import time
from types import SimpleNamespace

import pytest
from nav_msgs.msg import Odometry
from rclpy.node import Node

from harness import DEEP_QOS, Harness
from robotino_sim_node.odom_sources import check_single_odom_source, other_publishers
from robotino_geom_mpc.ros.parameters import NodeStartError
from robotino_geom_mpc.system.processes import ros_args


def _info(namespace: str, name: str) -> SimpleNamespace:
    return SimpleNamespace(node_namespace=namespace, node_name=name)


@pytest.mark.unit
def test_the_own_publisher_is_left_out_once():
    own = _info("/robot1", "robotino_plant")
    assert other_publishers([own], "robotino_plant", "/robot1") == []
    assert other_publishers([own, _info("/robot1", "robotino_node")], "robotino_plant", "/robot1") == \
        ["/robot1/robotino_node"]
    # a second simulator of the same name and namespace is another source
    assert other_publishers([own, own], "robotino_plant", "/robot1") == ["/robot1/robotino_plant"]
    assert other_publishers([_info("/", "driver")], "robotino_plant", "/") == ["/driver"]


class _Graph:
    """A node's graph queries (`check_single_odom_source` asks these): the publishers of one topic, its own name."""

    def __init__(self, publishers: list[SimpleNamespace]) -> None:
        self.publishers = publishers

    def get_publishers_info_by_topic(self, topic: str) -> list[SimpleNamespace]:
        assert topic == "/robot1/odom"
        return self.publishers

    def get_name(self) -> str:
        return "robotino_plant"

    def get_namespace(self) -> str:
        return "/robot1"


@pytest.mark.unit
def test_the_check_polls_meanwhile_at_each_look_until_its_window_has_passed():
    """The lockstep plant polls its start handshake here: its settle runs during the window, not after it."""
    own = SimpleNamespace(topic_name="/robot1/odom")
    looks: list[float] = []
    since = time.monotonic()
    check_single_odom_source(_Graph([_info("/robot1", "robotino_plant")]), own, since, 0.15, looks.append)
    assert len(looks) >= 3 and looks == sorted(looks)
    assert looks[0] >= since and looks[-1] >= since + 0.15  # the last look is the one past the window
    # another publisher: refused at the first look, which meanwhile saw too
    looks.clear()
    with pytest.raises(NodeStartError, match="/robot1/robotino_node"):
        check_single_odom_source(_Graph([_info("/robot1", "robotino_plant"), _info("/robot1", "robotino_node")]),
                                 own, time.monotonic(), 5.0, looks.append)
    assert len(looks) == 1


def _plant(namespace: str) -> subprocess.Popen:
    args = ros_args(None, {"mode": "realtime", "odom_publisher_check_s": 3.0})
    if namespace:
        args += ["-r", f"__ns:={namespace}"]
    return subprocess.Popen([sys.executable, "-m", "robotino_sim_node.plant_node", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.mark.ros
@pytest.mark.parametrize("plant_namespace, refused", [("/robot1", True), ("/robot2", False)])
def test_the_plant_refuses_to_start_beside_another_odometry_publisher(plant_namespace, refused):
    with Harness("odom_source_test") as h:
        standin = Node("standin_odom", namespace="/robot1", context=h.context)
        standin.create_publisher(Odometry, "odom", 10)  # /robot1/odom, never published on
        h.executor.add_node(standin)
        received = {topic: h.collect(f"{plant_namespace}/{topic}", Odometry, DEEP_QOS)
                    for topic in ("odom", "ground_truth/odom")}
        h.spin_for(0.5)  # the stand-in is on the graph before the plant starts
        plant = _plant(plant_namespace)
        try:
            if refused:
                assert h.spin_until(lambda: plant.poll() is not None, 60.0)
                h.spin_for(0.5)  # anything it had sent would be here by now
            else:  # it starts and publishes its odometry
                assert h.spin_until(lambda: len(received["odom"]) >= 10, 60.0), plant.stderr
        finally:
            if plant.poll() is None:
                plant.terminate()
            _, stderr = plant.communicate(timeout=30)
    if refused:
        assert plant.returncode == 2, stderr
        assert "another publisher of /robot1/odom is on the ROS graph: /robot1/standin_odom" in stderr, stderr
        assert "Traceback" not in stderr
        assert received == {"odom": [], "ground_truth/odom": []}
    else:
        assert plant.returncode == 0, stderr
        assert "another publisher" not in stderr
