"""The lockstep plant's start handshake: tick 0 goes out once the loop's subscriptions are there and have settled.

Tick 0 goes out only when the ``wheel_voltages`` publisher is matched and
every ``lockstep_wait_for`` entry ``topic:count`` has that many
subscriptions (matched readers of the plant's own publishers, the graph
for other topics: the controller, the trajectory, a recorder) and has been
for ``lockstep_settle_s``: the graph shows another node's endpoint before
the nodes that talk to it have matched it (a controller's wheel_voltages
writer and a recorder's reader can match up to a discovery announcement
period later), and what is published before a match is lost to that
reader. The wait is never silent: after `REPORT_AFTER_S` a warning names
what is missing (``topic have/need``), every `REPORT_EVERY_S`.
"""

from __future__ import annotations

from collections.abc import Iterable

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription

from robotino_geom_mpc.ros.parameters import NodeStartError

__all__ = ["DEFAULT_WAIT_FOR", "REPORT_AFTER_S", "REPORT_EVERY_S", "parse_wait_for", "StartHandshake"]

DEFAULT_WAIT_FOR = ("odom:1", "/clock:1")  # the controller; the trajectory
REPORT_AFTER_S = 1.0  # a shorter wait is discovery at work: not reported
REPORT_EVERY_S = 2.0
_PARAMETER = "lockstep_wait_for"


def parse_wait_for(entries: Iterable[object] | None) -> list[tuple[str, int]]:
    """``topic:count`` entries as (topic, count); ValueError naming a malformed entry."""
    out = []
    for entry in entries or []:
        topic, _, count = str(entry).rpartition(":")
        if not topic or not count.isdigit():
            raise ValueError(f"parameter '{_PARAMETER}': entry {entry!r} is not 'topic:count'")
        out.append((topic, int(count)))
    return out


def _check_wait_for(params: list[Parameter]) -> SetParametersResult:
    for param in params:
        if param.name == _PARAMETER:
            try:
                parse_wait_for(param.value)
            except ValueError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
    return SetParametersResult(successful=True)


class StartHandshake:
    """Declares ``lockstep_wait_for`` on `node` and tells when tick 0 may go out.

    Parameters
    ----------
    node
        The plant node (its graph, logger and parameters).
    command_sub
        The ``wheel_voltages`` subscription: one matched publisher is needed.
    own
        The plant's publishers by topic name (their matched readers count, not the graph).
    """

    def __init__(self, node: Node, command_sub: Subscription, own: dict[str, Publisher | None]) -> None:
        node.declare_parameter(
            _PARAMETER,
            list(DEFAULT_WAIT_FOR),
            ParameterDescriptor(
                description="Lockstep: 'topic:count' entries, at least count subscriptions on each topic before "
                "tick 0 (the plant's own publishers count matched readers, other topics the graph)",
                additional_constraints="each entry 'topic:count' with count >= 0",
            ),
        )
        node.add_on_set_parameters_callback(_check_wait_for)
        try:
            parse_wait_for(node.get_parameter(_PARAMETER).value)
        except ValueError as exc:
            raise NodeStartError(str(exc)) from None
        self.node, self.command_sub, self.own = node, command_sub, own
        self.created_at: float | None = None
        self.ready_since: float | None = None  # since when the handshake is met
        self.reported_at: float | None = None

    def _subscribers_of(self, topic: str) -> int:
        pub = self.own.get(topic)
        return pub.get_subscription_count() if pub is not None else self.node.count_subscribers(topic)

    def missing(self) -> list[str]:
        """What the handshake still waits for, as ``topic have/need`` (empty when met)."""
        out = []
        publishers = self.command_sub.get_publisher_count()
        if publishers < 1:
            out.append(f"wheel_voltages publishers {publishers}/1")
        for topic, count in parse_wait_for(self.node.get_parameter(_PARAMETER).value):
            have = self._subscribers_of(topic)
            if have < count:
                out.append(f"{topic} subscriptions {have}/{count}")
        return out

    def poll(self, now: float, settle_s: float) -> bool:
        """True when tick 0 may go out at steady time `now` [s]; logs what is missing (throttled)."""
        if self.created_at is None:
            self.created_at = now
        missing = self.missing()
        if missing:
            self.ready_since = None
            if now - self.created_at >= REPORT_AFTER_S and (
                    self.reported_at is None or now - self.reported_at >= REPORT_EVERY_S):
                self.reported_at = now
                self.node.get_logger().warn(
                    f"waiting {now - self.created_at:.1f} s before tick 0 for: {', '.join(missing)}")
            return False
        if self.ready_since is None:
            self.ready_since = now
        return now - self.ready_since >= settle_s
