"""One source at a time on ROS: the publishers of an input told apart, a refused one named from the graph.

The decision is the loops' (`loop.source_pairing.SourcePairing`: in `loop.robot_loop.RobotLoop.admit` for the plant,
in the command buffer's own pairing, in `loop.controller_loop.ControllerLoop` for the previews); `SourceGate` is the
node's half: the source of each message (`PublicationStreams` over the message info's
``publication_sequence_number``: this rclpy gives no publisher GID with a message), the graph's publishers of the
topic taken when a source takes the lease (the paired publisher), and, for a refused message, a throttled warning
naming the topic's other publishers (node, namespace, GID) and the values the node's diagnostics carry.

The subscriptions take the message info through `WithInfo`: rclpy 7.1's EventsExecutor (the nodes' executor, `ros.spin`)
calls a (msg, info) callback with the pair as one tuple, the other executors with two arguments.

``pairing.lease_s`` (`PAIRING_SPECS`, the plant and the command buffer): how long the lease holds without a
message of its holder.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from typing import Any

from rclpy.node import Node

from robotino_geom_mpc.loop.source_pairing import PublicationStreams, SourcePairing
from robotino_geom_mpc.params.specs import ParamSpec
from robotino_geom_mpc.ros.throttle import log_throttled

__all__ = ["PAIRING_DEFAULTS", "PAIRING_SPECS", "SourceGate", "WithInfo"]

PAIRING_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("pairing.lease_s", float, "One controller at a time: the first to command after the start or a "
              "~/release takes the robot; another's commands are refused (counted, logged) while it has sent within "
              "this time", "s", 0.0, 3600.0, True),
)
PAIRING_DEFAULTS = {"pairing.lease_s": 0.5}


class WithInfo:
    """A subscription callback `handler(msg, info)` that rclpy calls with the message info under every executor
    (module docstring): its signature says (msg, info), so rclpy passes the info.
    """

    __signature__ = inspect.Signature([inspect.Parameter("msg", inspect.Parameter.POSITIONAL_ONLY),
                                       inspect.Parameter("info", inspect.Parameter.POSITIONAL_ONLY)])

    def __init__(self, handler: Callable[[Any, dict[str, Any]], None]) -> None:
        self.handler = handler

    def __call__(self, *received: Any) -> None:
        msg, info = received[0] if len(received) == 1 else received
        self.handler(msg, info)


def _gid(endpoint: Any) -> bytes:
    return bytes(endpoint.endpoint_gid)


def _name(endpoint: Any) -> str:
    namespace = endpoint.node_namespace.rstrip("/")
    return f"{namespace}/{endpoint.node_name} (gid {_gid(endpoint).hex()})"


class SourceGate:
    """The node's half of a pairing on `topic` (module docstring).

    Parameters
    ----------
    node
        The receiving node (its graph, its logger).
    topic
        The input's topic as the node subscribes it (relative names resolve in the node's namespace).
    """

    def __init__(self, node: Node, topic: str) -> None:
        self.node = node
        self.topic = node.resolve_topic_name(topic)
        self.streams = PublicationStreams()
        self.paired: set[bytes] = set()  # the GIDs of the topic's publishers when the lease was last taken
        self.paired_names = "none"
        self.intruders = "none"  # the other publishers named at the last refusal
        self._handovers = 0
        self._named_at = -1e9  # steady time of the last naming of the intruders (a graph query; once a second)

    def source(self, info: dict[str, Any]) -> bytes:
        """The source of a message with the message info `info` (a subscription's second argument)."""
        return self.streams.source(info.get("publication_sequence_number"), time.monotonic_ns())

    def note(self, pairing: SourcePairing) -> None:
        """After a message taken: on a new lease, the topic's publishers now are the paired one(s)."""
        if pairing.handovers != self._handovers:
            self._handovers = pairing.handovers
            publishers = self.node.get_publishers_info_by_topic(self.topic)
            self.paired = {_gid(p) for p in publishers}
            self.paired_names = ", ".join(_name(p) for p in publishers) or "unknown"
            if pairing.handovers > 1:
                self.node.get_logger().info(f"{self.topic}: paired with {self.paired_names} (lease {pairing.holder!r})")

    def refused(self, pairing: SourcePairing, source: bytes) -> None:
        """A message of `source` refused: a throttled warning naming the topic's other publishers on the graph."""
        now = time.monotonic()
        if now - self._named_at >= 1.0:
            self._named_at = now
            publishers = self.node.get_publishers_info_by_topic(self.topic)
            others = [_name(p) for p in publishers if _gid(p) not in self.paired] or [_name(p) for p in publishers]
            self.intruders = ", ".join(others) or "unknown"
        log_throttled(self.node.get_logger(), "WARN",
                      f"refused {self.topic} from a second source ({self.intruders}; stream {source.decode()}, "
                      f"{pairing.refused.get(source, 0)} refused): paired with {self.paired_names} until its lease "
                      f"lapses or ~/release", 2.0, f"second_source {self.topic}")

    def released(self, pairing: SourcePairing, holder: bytes | None) -> str:
        """The answer of ``~/release`` (the lease `holder` had, None: none)."""
        if holder is None:
            return f"{self.topic}: no lease held; the next source takes it"
        was = self.paired_names
        self.paired, self.paired_names = set(), "none"
        self.node.get_logger().info(f"{self.topic}: lease of {was} released; the next source takes it")
        return f"{self.topic}: released {was}; the next source takes it"

    def status(self, pairing: SourcePairing) -> dict[str, str]:
        """The diagnostics' values: the paired publisher(s), the refusals, the last intruder named."""
        return {"paired_source": self.paired_names if pairing.holder is not None else "none",
                "refused_second_source": str(pairing.refused_total), "second_source": self.intruders}
