"""A small rclpy harness for talking to running nodes: collect topics, publish, set parameters (tests, bench).

It owns its own `rclpy.Context` (so it can live beside anything else in the
process) and spins only when asked (`spin_until`), in the calling thread.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import rclpy
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["Harness", "DEEP_QOS"]

# keep-all and reliable: nothing is lost while the harness is not spinning or lags behind a lockstep loop
# (a keep-last queue, however deep, drops its oldest samples once the reader lags by more than its depth)
DEEP_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


class Harness:
    """A node in its own context; use as a context manager.

    Parameters
    ----------
    name
        Node name.
    """

    def __init__(self, name: str = "robotino_harness") -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def collect(self, topic: str, msg_type: type, qos: QoSProfile = DEEP_QOS) -> list:
        """Subscribe `topic`; returns the list the messages are appended to (in arrival order)."""
        received: list = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        """Spin until `predicate()` is true (True) or `timeout_s` passes (False)."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def spin_for(self, seconds: float) -> None:
        """Spin for `seconds`."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def _call(self, client, request, timeout_s: float):
        if not client.wait_for_service(timeout_sec=timeout_s):
            raise TimeoutError(f"service {client.srv_name} not available")
        future = client.call_async(request)
        if not self.spin_until(future.done, timeout_s):
            raise TimeoutError(f"no answer from {client.srv_name}")
        return future.result()

    def set_parameters(self, node_name: str, values: dict[str, Any], timeout_s: float = 10.0) -> list:
        """Set parameters of a remote node; returns its `SetParametersResult` list."""
        from rclpy.parameter import Parameter

        client = self.node.create_client(SetParameters, f"/{node_name}/set_parameters")
        request = SetParameters.Request()
        request.parameters = [Parameter(name, value=value).to_parameter_msg() for name, value in values.items()]
        try:
            return list(self._call(client, request, timeout_s).results)
        finally:
            self.node.destroy_client(client)

    def get_parameters(self, node_name: str, names: list[str], timeout_s: float = 10.0) -> list[Any]:
        """Values of parameters of a remote node."""
        from rclpy.parameter import parameter_value_to_python

        client = self.node.create_client(GetParameters, f"/{node_name}/get_parameters")
        try:
            result = self._call(client, GetParameters.Request(names=names), timeout_s)
        finally:
            self.node.destroy_client(client)
        return [parameter_value_to_python(v) for v in result.values]

    def close(self) -> None:
        """Destroy the node and shut the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()

    def __enter__(self) -> Harness:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
