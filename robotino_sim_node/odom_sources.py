"""The plant's start check: no other publisher of its ``odom`` topic on the ROS graph (two sources of odometry are a
fault: a real driver's beside the simulator's, or a second simulator).

`check_single_odom_source` runs in the plant node's construction, after its publishers and subscriptions exist (DDS
matches them in the background meanwhile, and the caller's `meanwhile` is polled: the lockstep start handshake's
settle runs during the window, not after it) and before anything is published or any callback runs. It polls the
graph until the window ``odom_publisher_check_s``, counted from the node's creation, has passed: discovery of a
participant that existed before takes tens of milliseconds to about a second on one host (Fast DDS; longer where its
announcements are lost). Its own publisher is on the graph too and is left out by node name and namespace, once. A
publisher can show before its node's name does (rmw sends the nodes of a participant apart from its endpoints): the
check then waits up to `NAME_WAIT_S` more for the name.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from robotino_geom_mpc.params.specs import ParamSpec

__all__ = ["ODOM_CHECK_DEFAULTS", "ODOM_CHECK_SPECS", "check_single_odom_source", "other_publishers"]

ODOM_CHECK_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("odom_publisher_check_s", float, "At start, how long the node looks on the ROS graph for another "
              "publisher of its odom topic before it publishes anything (counted from the node's creation; 0: the "
              "graph as known then). One found: an error naming it and exit status 2 (two sources of odometry are "
              "a fault)", "s", 0.0, 60.0, False),
)
ODOM_CHECK_DEFAULTS = {"odom_publisher_check_s": 1.0}
NAME_WAIT_S = 1.0
_POLL_S = 0.02
_UNKNOWN = "_UNKNOWN_"  # in rmw's placeholders of a node not (yet) known: _NODE_NAME_UNKNOWN_, _NODE_NAMESPACE_UNKNOWN_


def other_publishers(infos: list[Any], name: str, namespace: str) -> list[str]:
    """The fully qualified node names of the publishers `infos` (rclpy `TopicEndpointInfo`) but one of node
    `name` in `namespace` (the caller's own publisher).
    """
    names = [(info.node_namespace, info.node_name) for info in infos]
    if (namespace, name) in names:
        names.remove((namespace, name))
    return [f"{ns.rstrip('/')}/{node}" for ns, node in names]


def check_single_odom_source(node: Any, publisher: Any, since: float, window_s: float,
                             meanwhile: Callable[[float], object] | None = None) -> None:
    """Return once `window_s` after `since` (steady time) has passed with `publisher` the only one of its topic;
    `meanwhile` (if given) is called with the steady time at each look.

    Raises
    ------
    NodeStartError
        Naming the other publishers (node names from the graph) as soon as one is seen.
    """
    from robotino_geom_mpc.ros.parameters import NodeStartError  # (rclpy: not at this plain module's import)

    topic = publisher.topic_name  # resolved: namespace and remaps applied
    seen = None  # when another publisher was first seen
    while True:
        infos = node.get_publishers_info_by_topic(topic)
        others = other_publishers(infos, node.get_name(), node.get_namespace()) if len(infos) > 1 else []
        now = time.monotonic()
        if meanwhile is not None:
            meanwhile(now)
        if not others:
            seen = None
            if now >= since + window_s:
                return
        else:
            seen = now if seen is None else seen
            if all(_UNKNOWN not in name for name in others) or now >= seen + NAME_WAIT_S:
                raise NodeStartError(
                    f"another publisher of {topic} is on the ROS graph: {', '.join(others)}; two sources of "
                    f"odometry are a fault, so this simulator does not start (stop the other, or run the simulator "
                    f"in another namespace)")
        time.sleep(_POLL_S)
