"""Launch the Robotino loop: plant simulator, trajectory, controller and (optionally) the recorder.

    ros2 launch robotino_geom_mpc robotino_geom_mpc.launch.py scenario:=robustness lockstep:=true

Launch arguments
----------------
scenario       a scenario of ``robotino_geom_mpc.scenarios``: paper-circle | lemniscate | point-to-point |
               robustness. Each node gets the scenario's overrides (``scenarios.node_parameters``): the
               trajectory the scenario (its reference), the controller its model (mismatched in
               robustness), the plant the odometry noise
params_file    ROS 2 parameter file, ``/**`` section read by every node (default: config/robotino3.yaml);
               the controller's mismatched model is scaled from its robot
plant_params   parameter file of the plant alone (default: params_file); a different one gives a
               plant-robot mismatch
lockstep       true: the plant owns time: it publishes /clock and advances one control period per
               command (deterministic, faster than real time). No node uses sim time: the trajectory is
               driven by the /clock messages, the controller by the odometry stamps (a time source would
               cost each a /clock wake-up a tick). false: wall-clock timers
duration       run length [s]; 0 runs until stopped
seed           seed of the plant's odometry noise
record         true: also start the MCAP recorder (bag in ``bag``)
bag            recording directory (default: rosbag2_<date> in the working directory)

The scenario is resolved when the launch runs (an ``OpaqueFunction``): an unknown name stops the launch
with the closest valid one. With ``record:=true`` the lockstep plant also waits for the recorder's
subscriptions (``lockstep_wait_for``), so the recording holds tick 0. Without ``ros2 launch``,
``robotino-geom-mpc run`` starts the same processes and also writes metrics.json and the figures
from the recording.
"""

import math

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from robotino_geom_mpc.core.params import load_params
from robotino_geom_mpc.ros.processes import RECORDER_WAIT_FOR
from robotino_geom_mpc.scenarios import node_parameters

PACKAGE = "robotino_geom_mpc"


def _flag(config: dict, name: str) -> bool:
    """A true/false launch argument (as launch's conditions read it: true, false, 1, 0)."""
    value = config[name].strip().lower()
    if value not in ("true", "false", "1", "0"):
        raise ValueError(f"launch argument '{name}' must be true or false, got {config[name]!r}")
    return value in ("true", "1")


def _number(config: dict, name: str, kind: type = float) -> float:
    """A non-negative finite number from a launch argument."""
    try:
        value = kind(config[name])
    except ValueError:
        raise ValueError(f"launch argument '{name}' must be a number, got {config[name]!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"launch argument '{name}' must be finite and >= 0, got {config[name]!r}")
    return value


def _nodes(context) -> list:
    """The nodes of the run, each with its scenario's overrides (`scenarios.node_parameters`)."""
    config = context.launch_configurations
    scenario, params_file = config["scenario"], config["params_file"]
    robot, _ = load_params(params_file)
    overrides = node_parameters(scenario, robot)
    mode = "lockstep" if _flag(config, "lockstep") else "realtime"
    record = _flag(config, "record")
    plant = {**overrides["plant_node"], "mode": mode, "duration_s": _number(config, "duration"),
             "seed": _number(config, "seed", int)}
    if record:  # the lockstep plant also waits for the recorder's subscriptions
        plant["lockstep_wait_for"] = list(RECORDER_WAIT_FOR)
    nodes = [
        Node(package=PACKAGE, executable="trajectory_node", name="robotino_trajectory", output="screen",
             parameters=[params_file, {**overrides["trajectory_node"], "mode": mode}]),
        Node(package=PACKAGE, executable="controller_node", name="robotino_controller", output="screen",
             parameters=[params_file, {**overrides["controller_node"], "mode": mode}]),
        Node(package=PACKAGE, executable="plant_node", name="robotino_plant", output="screen",
             parameters=[config["plant_params"], plant]),
    ]
    if record:
        nodes.append(Node(package=PACKAGE, executable="recorder_node", name="recorder", output="screen",
                          parameters=[params_file, {"output": config["bag"], "scenario": scenario}]))
    return nodes


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "robotino3.yaml"])
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="paper-circle", description="scenario (scenarios.py)"),
        DeclareLaunchArgument("params_file", default_value=default_params, description="parameter file (/** section)"),
        DeclareLaunchArgument("plant_params", default_value=LaunchConfiguration("params_file"),
                              description="parameter file of the plant"),
        DeclareLaunchArgument("lockstep", default_value="true", description="the plant drives /clock (true/false)"),
        DeclareLaunchArgument("duration", default_value="0.0", description="run length [s], 0: until stopped"),
        DeclareLaunchArgument("seed", default_value="0", description="seed of the odometry noise"),
        DeclareLaunchArgument("record", default_value="false", description="start the MCAP recorder"),
        DeclareLaunchArgument("bag", default_value="", description="recording directory"),
        OpaqueFunction(function=_nodes),
    ])
