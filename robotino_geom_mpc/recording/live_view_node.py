"""Live view node: every topic of the running system served over the Foxglove WebSocket protocol (no ROS desktop).

``run --foxglove [PORT]`` starts it beside the loop; a Foxglove user connects to ``ws://localhost:PORT`` (default
8765) and sees the run as it happens: the robot in the 3D panel (its URDF on ``robot_description``, its frames on
``/tf``), odometry, currents, voltages, diagnostics. The server is the Foxglove SDK's (`foxglove.start_server`).

Topics are picked up as they appear (the graph polled every ``discovery_period_s``, as the recorder does) and
subscribed serialized (``raw=True``); each becomes one SDK channel with the topic's ``ros2msg`` schema (the text a
recording stores, `recording.definitions.message_definition`) and message encoding ``cdr``, and every sample's CDR
bytes go to it as they are, with the receive time (system clock) as log time: nothing is decoded or re-encoded.

QoS: as the recorder's (`ros.bag_qos.adapt_request_to_offers`: reliable / transient local only when every
publisher offers it, so the latched URDF and reference path reach a viewer that connects late) but keep-last
`QUEUE_DEPTH`: a watcher never holds the loop back (a reliable keep-last reader acknowledges what it receives
whether or not it was taken). A client sees what is published after it subscribed; the last sample of a latched
(transient-local) topic is logged again whenever a client subscribes to it, so the URDF reaches every viewer.

Known SDK race (foxglove-sdk 0.30): a channel is advertised to a client just before the server registers it for
that client, so a subscription sent the instant the advertisement arrives can be refused (``Unknown channel ID``);
a client subscribes again then (test_live_view's does).

Parameters: ``port``, ``host`` (default 127.0.0.1: this machine only; 0.0.0.0 serves the network),
``discovery_period_s``.
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy

from robotino_geom_mpc.params.specs import ParamSpec
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.definitions import message_class, message_definition
from robotino_geom_mpc.ros.bag_qos import adapt_request_to_offers
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters
from robotino_geom_mpc.ros.spin import run_node

__all__ = ["DEFAULT_PORT", "LIVE_VIEW_SPECS", "QUEUE_DEPTH", "LiveViewNode", "main"]

DEFAULT_PORT = 8765  # Foxglove's default WebSocket port
QUEUE_DEPTH = 100  # the subscriptions' keep-last history
LIVE_VIEW_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("port", int, "TCP port of the Foxglove WebSocket server (0: any free port, logged)", "", 0, 65535,
              False),
    ParamSpec("host", str, "Address the server binds to (127.0.0.1: this machine only; 0.0.0.0: every interface)"),
    ParamSpec("discovery_period_s", float, "Period of the graph polling for new topics", "s", 0.01, 10.0, False),
)
_DEFAULTS = {"port": DEFAULT_PORT, "host": "127.0.0.1", "discovery_period_s": 0.1}


def _listener(node: LiveViewNode) -> Any:
    """The server's listener: a new subscriber of a latched channel gets its last sample again."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client: Any, channel: Any) -> None:
            node.resend_latched(channel.topic)

    return Listener()


class LiveViewNode(Node):
    """The live view (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("robotino_live_view", **kwargs)
        import foxglove

        self.params = SpecParameters(self, LIVE_VIEW_SPECS, _DEFAULTS, fixed=tuple(_DEFAULTS))
        self._foxglove = foxglove
        try:
            self.server = foxglove.start_server(name="robotino_geom_mpc", host=self.params["host"],
                                                port=self.params["port"], server_listener=_listener(self))
        except Exception as exc:  # the SDK raises its own error types (address in use, bad host)
            raise NodeStartError(f"cannot serve on {self.params['host']}:{self.params['port']}: {exc}") from None
        self.channels: dict[str, Any] = {}  # topic -> SDK channel (None: a type without definition)
        self.latched: dict[str, bytes] = {}  # transient-local topic -> its last sample
        self.subscriptions_by_topic: dict[str, Any] = {}
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.params["discovery_period_s"], self._discover, clock=steady)
        self._discover()
        self.get_logger().info(f"Foxglove live view on ws://{self.params['host']}:{self.server.port}")

    def _discover(self) -> None:
        """Serve every topic that has a publisher and is not served yet."""
        for name, types in self.get_topic_names_and_types():
            if name in self.channels or any(part.startswith("_") for part in name.split("/") if part):
                continue
            infos = self.get_publishers_info_by_topic(name)
            if not infos:
                continue
            type_name = types[0]
            try:
                cls, text = message_class(type_name), message_definition(type_name)
            except BagError as exc:
                self.get_logger().error(f"cannot serve {name}: {exc}")
                self.channels[name] = None
                continue
            fox = self._foxglove
            channel = fox.Channel(name, message_encoding="cdr",
                                  schema=fox.Schema(name=type_name, encoding="ros2msg", data=text.encode()))
            self.channels[name] = channel
            qos = adapt_request_to_offers([i.qos_profile for i in infos], QUEUE_DEPTH)
            latched = qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
            self.subscriptions_by_topic[name] = self.create_subscription(
                cls, name, self._forward(name, channel, latched), qos, raw=True)
            self.get_logger().info(f"serving {name} [{type_name}]")

    def _forward(self, topic: str, channel: Any, latched: bool):
        def forward(data: bytes) -> None:
            if latched:
                self.latched[topic] = data
            channel.log(data, log_time=time.time_ns())

        return forward

    def resend_latched(self, topic: str) -> None:
        """Log the last sample of a latched `topic` again (for a client that just subscribed)."""
        data = self.latched.get(topic)
        channel = self.channels.get(topic)
        if data is not None and channel is not None:
            channel.log(data, log_time=time.time_ns())

    def on_stop(self) -> None:
        """Stop the server as the node stops (`ros.spin.run_node`): the clients see it close."""
        self.server.stop()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``python -m robotino_geom_mpc.recording.live_view_node``."""
    return run_node(LiveViewNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
