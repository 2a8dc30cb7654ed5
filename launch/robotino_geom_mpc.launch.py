"""Launch the Robotino loop: plant simulator, trajectory, controller and (optionally) the recorder.

    ros2 launch robotino_geom_mpc robotino_geom_mpc.launch.py scenario:=lemniscate lockstep:=true

Launch arguments
----------------
scenario       paper-circle | lemniscate | point-to-point | robustness (reference; see `simulate`)
params_file    ROS 2 parameter file, ``/**`` section read by every node (default: config/robotino3.yaml)
plant_params   parameter file of the plant alone (default: params_file); a different one gives a
               plant-robot mismatch
lockstep       true: the plant drives /clock and advances one control period per command, every node
               uses sim time (deterministic, faster than real time); false: wall-clock timers
duration       run length [s]; 0 runs until stopped
record         true: also start the MCAP recorder (bag in ``bag``)
bag            recording directory (default: rosbag2_<date> in the working directory)

With ``record:=true`` the lockstep plant also waits for the recorder's subscriptions
(``lockstep_wait_for``), so the recording holds tick 0. Without ``ros2 launch``,
``robotino-geom-mpc run`` starts the same processes and also writes metrics.json and the figures
from the recording.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from robotino_geom_mpc.ros.processes import RECORDER_WAIT_FOR

PACKAGE = "robotino_geom_mpc"


def generate_launch_description() -> LaunchDescription:
    scenario = LaunchConfiguration("scenario")
    params_file = LaunchConfiguration("params_file")
    plant_params = LaunchConfiguration("plant_params")
    lockstep = LaunchConfiguration("lockstep")
    duration = LaunchConfiguration("duration")
    record = LaunchConfiguration("record")
    mode = PythonExpression(["'lockstep' if '", lockstep, "'.lower() == 'true' else 'realtime'"])
    default_params = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "robotino3.yaml"])

    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="paper-circle", description="reference scenario"),
        DeclareLaunchArgument("params_file", default_value=default_params, description="parameter file (/** section)"),
        DeclareLaunchArgument("plant_params", default_value=params_file, description="parameter file of the plant"),
        DeclareLaunchArgument("lockstep", default_value="true", description="plant-driven sim time (true/false)"),
        DeclareLaunchArgument("duration", default_value="0.0", description="run length [s], 0: until stopped"),
        DeclareLaunchArgument("record", default_value="false", description="start the MCAP recorder"),
        DeclareLaunchArgument("bag", default_value="", description="recording directory"),
        # no use_sim_time: in lockstep the trajectory's time is the /clock messages and the controller's the
        # odometry stamps (see the nodes' docstrings); a time source would cost each a /clock wake-up a tick
        Node(
            package=PACKAGE, executable="trajectory_node", name="robotino_trajectory", output="screen",
            parameters=[params_file, {"scenario": scenario, "mode": mode}],
        ),
        Node(
            package=PACKAGE, executable="controller_node", name="robotino_controller", output="screen",
            parameters=[params_file, {"mode": mode}],
        ),
        Node(
            package=PACKAGE, executable="plant_node", name="robotino_plant", output="screen",
            condition=UnlessCondition(record),
            parameters=[plant_params, {"mode": mode, "duration_s": ParameterValue(duration, value_type=float)}],
        ),
        Node(  # the same, waiting in lockstep for the recorder's subscriptions too
            package=PACKAGE, executable="plant_node", name="robotino_plant", output="screen",
            condition=IfCondition(record),
            parameters=[plant_params, {"mode": mode, "duration_s": ParameterValue(duration, value_type=float),
                                       "lockstep_wait_for": list(RECORDER_WAIT_FOR)}],
        ),
        Node(
            package=PACKAGE, executable="recorder_node", name="recorder", output="screen",
            condition=IfCondition(record),
            parameters=[params_file, {"output": LaunchConfiguration("bag"), "scenario": scenario}],
        ),
    ])
