"""A fleet process: one node per robot, each in its robot's namespace, all on one events executor.

A fleet node (`FleetHost`, e.g. ``/robotino_fleet_controller``) declares ``robots``, the robots' namespaces
(``[robot1, robot2, ...]``), and builds one node of the single-robot kind per robot, named as that node is in a
namespaced single-robot launch (``/robot1/robotino_controller``): every topic, service (``~/enable`` is
``/robot1/robotino_controller/enable``), parameter and diagnostic of a robot is where it would be with one
process per robot, and a parameter file's node sections (``/robot1/robotino_controller:``) set one robot's
parameters, its ``/**`` section every robot's. Each robot's ``frame_prefix`` is its namespace (``robot1/``), as
`system.processes.node_arguments` gives a namespaced robot. `ros.spin.run_nodes` spins them all on one executor.

A fleet node may declare fleet-wide parameters (``fleet_wide``): its value of each (its own, or a parameter file's
``/**`` section) is every robot's, e.g. the optional outputs a fleet leaves off by default (every robot's extra
message a tick is N messages a tick for the fleet's processes and its recorder).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from robotino_geom_mpc.ros.parameters import NodeStartError
from robotino_geom_mpc.ros.spin import run_nodes
from robotino_geom_mpc.system.processes import NamespaceError, frame_prefix, ros_namespace

__all__ = ["ROBOTS_PARAMETER", "FleetHost", "fleet_namespaces", "run_fleet"]

ROBOTS_PARAMETER = "robots"
# a ROS robot's node, built in `namespace` with these parameter overrides
RobotNodeFactory = Callable[[str, list[Parameter]], Node]


def fleet_namespaces(values: Sequence[Any]) -> list[str]:
    """``robots`` as absolute namespaces (``robot1`` -> ``/robot1``); ValueError naming a bad or repeated one."""
    out: list[str] = []
    for value in values:
        try:
            namespace = ros_namespace(str(value))
        except NamespaceError as exc:
            raise ValueError(f"parameter '{ROBOTS_PARAMETER}': {exc}") from None
        if not namespace:
            raise ValueError(f"parameter '{ROBOTS_PARAMETER}': {value!r} is no namespace (each robot needs its own)")
        if namespace in out:
            raise ValueError(f"parameter '{ROBOTS_PARAMETER}': {namespace} is named twice")
        out.append(namespace)
    if not out:
        raise ValueError(f"parameter '{ROBOTS_PARAMETER}': no robot")
    return out


class FleetHost(Node):
    """The fleet's own node: ``robots`` (read-only) and the robots' nodes built from it.

    Parameters
    ----------
    name
        The fleet node's name (e.g. ``robotino_fleet_controller``).
    build
        A robot's node: `build(namespace, overrides)`.
    fleet_wide
        Parameters of the fleet node that are every robot's: name -> (default, description).
    """

    def __init__(self, name: str, build: RobotNodeFactory,
                 fleet_wide: Mapping[str, tuple[Any, str]] | None = None) -> None:
        super().__init__(name)
        self.build = build
        self.fleet_wide = [
            Parameter(key, value=self.declare_parameter(key, default, ParameterDescriptor(
                description=f"{text} (the fleet's value is every robot's)", read_only=True)).value)
            for key, (default, text) in (fleet_wide or {}).items()]
        self.declare_parameter(ROBOTS_PARAMETER, ["robot1"], ParameterDescriptor(
            description="The robots' namespaces: one node of the single-robot kind per robot, in its namespace",
            additional_constraints="valid ROS namespaces, each named once, at least one", read_only=True))
        try:
            self.namespaces = fleet_namespaces(self.get_parameter(ROBOTS_PARAMETER).value)
        except ValueError as exc:
            raise NodeStartError(str(exc)) from None

    def robot_nodes(self) -> list[Node]:
        """One node per robot: `build(namespace, overrides)` with the robot's ``frame_prefix`` and the fleet-wide
        parameters.
        """
        return [self.build(ns, [Parameter("frame_prefix", value=frame_prefix(ns)), *self.fleet_wide])
                for ns in self.namespaces]


def run_fleet(host: Callable[[], FleetHost], args: list[str] | None = None) -> int:
    """The process of a fleet: the fleet node (`host()`) and its robots' nodes (`FleetHost.robot_nodes`) spun
    together (`ros.spin.run_nodes`).
    """

    def nodes() -> list[Node]:
        fleet = host()
        return [fleet, *fleet.robot_nodes()]

    return run_nodes(nodes, args)
