"""Fleet controller node: N robots' controllers in one process, each robot's tick through its own controller loop.

``/robotino_fleet_controller`` reads ``robots`` (the robots' namespaces, `ros.fleet`) and builds one
`controller_node.ControllerNode` per robot in its namespace: ``/robot1/robotino_controller`` subscribes
``/robot1/odom`` and ``/robot1/reference_preview`` and publishes ``/robot1/wheel_voltages`` (or ``cmd_vel``),
``/robot1/diagnostics``, ``/robot1/predicted_path`` and ``/robot1/controller_enabled``; its ``~/enable`` is
``/robot1/robotino_controller/enable`` and its parameters are its own (a parameter file's
``/robot1/robotino_controller:`` section; ``/**`` for every robot). Everything else is the single controller
node's (its module docstring): each robot's loop (`loop.controller_loop.ControllerLoop`), decoding and outputs
are that node's, so a robot's fault (stale odometry, a refused input, its watchdog) zeroes that robot only.
The fleet's own ``publish_predicted_path`` (default false; the report does not read it: with a recorder, which
subscribes every topic, every robot would compute and send its prediction every tick) is every robot's (`ros.fleet`).
All robots' callbacks run on one events executor (`ros.spin.run_nodes`): an odometry message costs the same
Python work as in the single node (decoded in place, one loop call, the outputs' CDR templates).
"""

from __future__ import annotations

from rclpy.node import Node
from rclpy.parameter import Parameter

from robotino_geom_mpc.nodes.controller_node import ControllerNode
from robotino_geom_mpc.ros.fleet import FleetHost, run_fleet

__all__ = ["fleet", "main"]

_FLEET_WIDE = {"publish_predicted_path": (False, "Publish predicted_path (while subscribed)")}


def _robot(namespace: str, overrides: list[Parameter]) -> Node:
    return ControllerNode(namespace=namespace, parameter_overrides=overrides)


def fleet() -> FleetHost:
    """The fleet's node (``/robotino_fleet_controller``), its robots' nodes not built yet (`FleetHost.robot_nodes`)."""
    return FleetHost("robotino_fleet_controller", _robot, _FLEET_WIDE)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc fleet_controller_node``."""
    return run_fleet(fleet, args)


if __name__ == "__main__":
    raise SystemExit(main())
