"""Rehearse the bring-up on a laptop without a robot: a stand-in for the robocup-logistics driver.

The plant simulator behind the emulated driver + firmware chain (``chain.active: enabled``,
``command_interface: cmd_vel``: odometry at 50 Hz dispatched and stamped by a 30 Hz driver loop, each
``cmd_vel`` forwarded once by that loop, the speed floor, the firmware's 20 ms tick, ramps, maxima and 0.5 s
motor timeout; docs/howto/real_robotino.md) as one process under the driver's node name (``robotino_node``)
and topics (``<namespace>/odom`` out, ``<namespace>/cmd_vel`` in; reliable, volatile). What no real driver
publishes (the emulation's ground truth, wheel currents, PI voltages) is moved under the hidden
``<namespace>/_standin/`` (`launch_arguments.STANDIN_HIDDEN`): no recording or report takes it for the robot's.

    ros2 launch robotino_geom_mpc driver_standin.launch.py          # instead of: ros2 launch rto_node ...

It runs until stopped (Ctrl-C). The plant refuses to start beside another ``odom`` publisher (a real driver).
Differences from the real driver that remain: one process and node (the real one has ``robotino_odometry_node``
publish ``odom``), the writer's history depth (100 against 10; the QoS policies that decide matching are the
same), and its odometry's frame ``odom`` (the driver's launch names it ``<namespace>/odom``).

Launch arguments
----------------
namespace      the driver's namespace (its launch argument; default none)
params_file    the emulated robot (default: config/robotino3.yaml, the preset)
seed           seed of the emulation's random streams
fastdds_profile  Fast DDS profile (default: $FASTRTPS_DEFAULT_PROFILES_FILE if set, else
               config/fastdds_localhost.xml); empty: none set by the launch
Arguments of the real driver's launch (``hostname``, ``launch_joynode``, ...) are accepted and ignored, so a
command line written for the driver starts the stand-in unchanged.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import EnvironmentVariable, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from robotino_geom_mpc.model.driver_chain import CHAIN_PRESETS
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.system.launch_arguments import DRIVER_NODE, STANDIN_HIDDEN, driver_remaps, node_environment, \
    number
from robotino_geom_mpc.system.processes import ros_namespace

PACKAGE = "robotino_geom_mpc"
PI_RATE_HZ = 200.0  # the wheel PI loops' rate (as `run --chain`): the emulation keeps up with the wall clock


def _nodes(context) -> list:
    """The plant node as the driver."""
    config = context.launch_configurations
    load_params(config["params_file"])  # a missing or malformed file stops the launch here
    namespace = ros_namespace(config["namespace"])
    plant = {"mode": "realtime", "command_interface": "cmd_vel", "chain.active": "enabled",
             **CHAIN_PRESETS["robocup-logistics"], "wheel_pi.rate_hz": PI_RATE_HZ, "duration_s": 0.0,
             "seed": number(config, "seed", int), "publish_tf": False}  # the driver's odom TF is off by default
    hidden = [(topic, f"{namespace}/_standin/{topic}") for topic in STANDIN_HIDDEN]
    return [Node(package=PACKAGE, executable="plant_node", name=DRIVER_NODE, namespace=namespace,
                 remappings=driver_remaps(namespace) + hidden, parameters=[config["params_file"], plant],
                 additional_env=node_environment(config), output="screen")]


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "robotino3.yaml"])
    default_profile = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "fastdds_localhost.xml"])
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="", description="the driver's namespace (default none)"),
        DeclareLaunchArgument("params_file", default_value=default_params, description="the emulated robot"),
        DeclareLaunchArgument("seed", default_value="0", description="seed of the emulation"),
        DeclareLaunchArgument("fastdds_profile",
                              default_value=EnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE",
                                                                default_value=default_profile),
                              description="Fast DDS profile; empty: none set by the launch"),
        OpaqueFunction(function=_nodes),
    ])
