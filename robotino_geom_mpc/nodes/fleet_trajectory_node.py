"""Fleet trajectory node: the references of N robots from one process, all on one clock.

``/robotino_fleet_trajectory`` reads ``robots`` (the robots' namespaces, `ros.fleet`) and builds one
`trajectory_node.TrajectoryNode` per robot in its namespace (``/robot1/robotino_trajectory`` publishes
``/robot1/reference_preview`` and ``/robot1/reference_path``; its parameters its own, e.g. a scenario per robot
from a parameter file's ``/robot1/robotino_trajectory:`` section). In lockstep every robot's node follows the one
global ``/clock`` of the fleet plant (`robotino_sim_node.fleet_plant_node`), so tick k is the same instant for
every robot and their references can be expressed together (a formation); in realtime each runs on the node clock.
"""

from __future__ import annotations

from rclpy.node import Node
from rclpy.parameter import Parameter

from robotino_geom_mpc.nodes.trajectory_node import TrajectoryNode
from robotino_geom_mpc.ros.fleet import FleetHost, run_fleet

__all__ = ["fleet", "main"]


def _robot(namespace: str, overrides: list[Parameter]) -> Node:
    return TrajectoryNode(namespace=namespace, parameter_overrides=overrides)


def fleet() -> FleetHost:
    """The fleet's node (``/robotino_fleet_trajectory``), its robots' nodes not built yet (`FleetHost.robot_nodes`)."""
    return FleetHost("robotino_fleet_trajectory", _robot)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc fleet_trajectory_node``."""
    return run_fleet(fleet, args)


if __name__ == "__main__":
    raise SystemExit(main())
