"""Launch what runs on a real Robotino's own PC in the command-buffer variant: ``command_buffer_node`` ALONE.

No simulator, no trajectory, no controller (those run off-board: docs/howto/real_robot_buffer.md). The buffer
takes the controller's ``cmd_vel_plan`` over the radio and publishes the driver's ``cmd_vel`` at the plans'
times, zero twist when they stop. (launch/robotino_geom_mpc.launch.py's ``command_buffer:=true`` is for
simulation: it starts the plant simulator too, whose ``odom`` beside the driver's would be a fault.)

    ros2 launch robotino_geom_mpc robot_side.launch.py params_file:=my_robotino3.yaml

Launch arguments
----------------
params_file    ROS 2 parameter file (default: config/robotino3_real.yaml); ``control.period_s`` must be the
               controller's, so give it the controller's file
namespace      the driver's namespace (its launch argument ``namespace``; default none, as the driver's); the
               buffer's ``cmd_vel`` is pinned to ``<namespace>/cmd_vel``, the driver's topic
fastdds_profile  Fast DDS profile (default: $FASTRTPS_DEFAULT_PROFILES_FILE if set, else
               config/fastdds_udp.xml: the buffer talks to the controller on another host); empty: none set
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import EnvironmentVariable, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.system.launch_arguments import driver_remaps, node_environment
from robotino_geom_mpc.system.processes import ros_namespace

PACKAGE = "robotino_geom_mpc"


def _nodes(context) -> list:
    """The command buffer, in the driver's namespace."""
    config = context.launch_configurations
    load_params(config["params_file"])  # a missing or malformed file stops the launch here
    namespace = ros_namespace(config["namespace"])
    return [Node(package=PACKAGE, executable="command_buffer_node", name="robotino_command_buffer",
                 namespace=namespace, remappings=driver_remaps(namespace), parameters=[config["params_file"]],
                 additional_env=node_environment(config), output="screen")]


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "robotino3_real.yaml"])
    default_profile = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "fastdds_udp.xml"])
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="parameter file (the controller's; default config/robotino3_real.yaml)"),
        DeclareLaunchArgument("namespace", default_value="", description="the driver's namespace (default none)"),
        DeclareLaunchArgument("fastdds_profile",
                              default_value=EnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE",
                                                                default_value=default_profile),
                              description="Fast DDS profile (default: $FASTRTPS_DEFAULT_PROFILES_FILE if set, "
                              "else config/fastdds_udp.xml); empty: none set by the launch"),
        OpaqueFunction(function=_nodes),
    ])
