"""Fleet plant node: N simulated Robotinos in one process, each publishing under its namespace.

``/robotino_fleet_plant`` reads ``robots`` (the robots' namespaces, `robotino_geom_mpc.ros.fleet`) and builds one
`plant_node.PlantNode` per robot in its namespace (``/robot1/robotino_plant``: ``/robot1/odom``,
``/robot1/ground_truth/odom``, ``/robot1/wheel_currents``, ... and its subscription ``/robot1/wheel_voltages``;
frames ``robot1/odom``, ``robot1/base_link``; its parameters its own, e.g. a seed per robot from a parameter
file's ``/robot1/robotino_plant:`` section), each over its own `loop.robot_loop.RobotLoop`.

Optional outputs: the fleet's own ``publish_tf`` and ``publish_joint_states`` (default false; a parameter file's
``/**`` section sets them too) are every robot's (`ros.fleet`): the report reads neither, and each costs every
robot a message a tick (published, and taken by a recorder). The rest of a robot's outputs is the single plant's.

Lockstep: one global ``/clock`` for the fleet (`plant_lockstep.FleetClock`): tick k + 1 goes out when every robot
has answered tick k, so the trajectory nodes (`nodes.fleet_trajectory_node`) follow one clock and each robot's run
is the single plant's run with its parameters. The robots share ``control.period_s`` and ``duration_s`` (checked
at the start, exit status 2 otherwise) and run without a link. Realtime: each robot is a realtime plant of its own
on the one executor.

The run's end: ``timing_report`` (this node's; the robots' own are not written) names the file the fleet's
timing goes to once every robot's run is over and every reader has acknowledged the samples: one JSON object,
per robot (the namespace without its slash) that robot's timing report (`loop_timing`: ``ticks``, ``missed``,
...).
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future

from robotino_geom_mpc.ros.fleet import FleetHost, run_fleet
from robotino_geom_mpc.ros.parameters import NodeStartError
from robotino_geom_mpc.ros.qos import wait_acknowledged
from robotino_geom_mpc.ros.spin import FINISHED_ACK_WAIT_S, data_publishers, monotonic
from robotino_sim_node.loop_timing import write_report
from robotino_sim_node.plant_lockstep import FleetClock
from robotino_sim_node.plant_node import PlantNode

__all__ = ["FleetPlant", "main"]

_SHARED = ("mode", "control.period_s", "duration_s")  # one value for the whole fleet
# off by default: the report reads neither
_FLEET_WIDE = {"publish_tf": (False, "Publish odom -> base_link on /tf"),
               "publish_joint_states": (False, "Publish the wheels on joint_states")}


class FleetPlant(FleetHost):
    """The fleet plant's node: the robots' plants (`PlantNode`, one `FleetClock`) and their end: the fleet's timing
    report, then ``done`` (`ros.spin.run_nodes` ends the spin on it).
    """

    def __init__(self) -> None:
        super().__init__("robotino_fleet_plant", self._plant, _FLEET_WIDE)
        self.declare_parameter("timing_report", "", ParameterDescriptor(
            description="File the fleet's timing goes to (per robot its timing report, one JSON object) once every "
            "robot's run is over; its folder must exist; empty: none", read_only=True))
        self.path = str(self.get_parameter("timing_report").value)
        if self.path and not Path(self.path).resolve().parent.is_dir():
            raise NodeStartError(f"parameter 'timing_report': folder of {self.path!r} does not exist")
        self.clock = FleetClock()
        self.created = monotonic()  # every robot's odometry sources' check counts its window from here
        self.robots: list[PlantNode] = []
        self.done: Future = Future()
        self.exit_status = 0

    def _plant(self, namespace: str, overrides: list[Parameter]) -> PlantNode:
        """A robot's plant on the fleet's clock (its own timing report not written: the fleet's gathers them)."""
        return PlantNode(self.clock, self.created, namespace=namespace,
                         parameter_overrides=[*overrides, Parameter("timing_report", value="")])

    def robot_nodes(self) -> list[Node]:
        """The robots' plants, checked to share `_SHARED`."""
        self.robots = cast("list[PlantNode]", super().robot_nodes())
        for name in _SHARED:
            values = {robot.get_namespace(): robot.params[name] for robot in self.robots}
            if len(set(values.values())) > 1:
                raise NodeStartError(f"parameter '{name}' differs between the fleet's robots ({values}): one value "
                                     "for all")
        for robot in self.robots:
            robot.done.add_done_callback(self._robot_done)
        return list(self.robots)

    def _robot_done(self, _: Future) -> None:
        if not all(robot.done.done() for robot in self.robots):
            return
        if self.path:
            wait_acknowledged(self, [pub for robot in self.robots for pub in data_publishers(robot)],
                              FINISHED_ACK_WAIT_S)
            report = {robot.get_namespace().lstrip("/"): robot.end.summary for robot in self.robots}
            try:
                write_report(self.path, report)
            except OSError as exc:
                self.get_logger().error(f"cannot write the fleet's timing report: {exc}")
                self.exit_status = 1
        self.done.set_result(True)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc fleet_plant_node``."""
    return run_fleet(FleetPlant, args)


if __name__ == "__main__":
    raise SystemExit(main())
