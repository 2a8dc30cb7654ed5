"""Launch the Robotino loop: plant simulator, trajectory, controller, robot description, optionally the recorder.

    ros2 launch robotino_geom_mpc robotino_geom_mpc.launch.py                  # paper-circle in real time
    ros2 launch robotino_geom_mpc robotino_geom_mpc.launch.py scenario:=robustness lockstep:=true
    ros2 launch robotino_geom_mpc robotino_geom_mpc.launch.py namespace:=robot1   # a second robot beside it
    ros2 launch robotino_geom_mpc robotino_geom_mpc.launch.py command_interface:=cmd_vel  # twists, wheel PI loops

Launch arguments
----------------
scenario       a name of ``robotino_geom_mpc.scenarios.SCENARIOS`` (the documentation's scenario page lists
               them, generated from it). Each node gets the scenario's overrides (``scenarios.node_parameters``): the
               trajectory the scenario (its reference), the controller its model (mismatched in
               robustness), the plant the odometry noise; over a scenario's link (wifi) the plant that link
               and, as with ``robotino-geom-mpc run``, plans: the controller's delay-compensated plans, the
               trajectory's preview as long as they need (``processes.scenario_parameters``)
params_file    ROS 2 parameter file, ``/**`` section read by every node (default: config/robotino3.yaml);
               the controller's mismatched model is scaled from its robot
plant_params   parameter file of the plant alone (default: params_file); a different one gives a
               plant-robot mismatch
lockstep       false (default): wall-clock timers, what someone watching in RViz expects. true: the
               plant owns time: it publishes /clock and advances one control period per command
               (deterministic, faster than real time). No node uses sim time: the trajectory is driven
               by the /clock messages, the controller by the odometry stamps (a time source would cost
               each a /clock wake-up a tick)
namespace      ROS namespace of every node (``robot1``; default none): the topics are relative and move
               with it; in lockstep the plant's /clock becomes <namespace>/clock, so several robots run in
               one domain (`processes.namespace_remaps`)
frame_prefix   prefix of the frame ids (odometry, /tf, the URDF's links), given to the nodes that declare
               it (`processes.FRAME_PREFIX_NODES`) and to the description publisher; ``auto`` (default):
               ``<namespace>/`` with a namespace, else none, so robots keep their frames apart on /tf
fastdds_profile  Fast DDS profile file of the nodes (FASTRTPS_DEFAULT_PROFILES_FILE; default: the one
               the environment sets, else config/fastdds_localhost.xml, quick announcements;
               config/fastdds_udp.xml across hosts); empty: none set by the launch
command_interface  voltages (default): the controller sends wheel_voltages to the plant's drives; cmd_vel:
               a base_link geometry_msgs/Twist on cmd_vel, held by the plant's wheel-speed PI loops (as a real
               Robotino's driver does). Given to the controller and the plant
duration       run length [s] of the plant; 0 runs until stopped. The plant ends the run: when it exits
               (its duration, or a failure) the launch shuts the other nodes down, as ``run`` stops them
seed           seed of the plant's odometry noise
command_buffer true: the variant of docs/howto/real_robot_buffer.md in simulation: also start the robot-side
               command buffer (``command_buffer_node``: ``cmd_vel_plan`` in, the driver's ``cmd_vel`` out at
               the plans' times, zero twist when they stop); the controller sends plans and no plain
               command (``publish_plain_command`` false), the plant is the driver (its ``cmd_vel``, no plans);
               needs ``command_interface:=cmd_vel``, realtime and a scenario without a link. On a real
               Robotino's PC start launch/robot_side.launch.py instead, which starts the buffer alone
record         true: also start the MCAP recorder (bag in ``bag``)
bag            recording directory (default: rosbag2_<date> in the working directory)
robots         N > 0: a fleet of N robots, ``robot1`` .. ``robotN`` (`ros.fleet`): the trajectory, the controller and
               the plant as one process each for the whole fleet (``fleet_trajectory_node``,
               ``fleet_controller_node``, ``fleet_plant_node``: one node per robot in its namespace, its frames
               prefixed ``robot<k>/``; in lockstep one /clock for the fleet; in realtime a preview every 10
               periods, `fleet_realtime_parameters`), no description publisher; with no
               ``namespace``, ``frame_prefix`` auto, no command buffer and a scenario without a link (as
               ``run --robots``). 0 (default): one robot
rviz           true: also start rviz2 with ``rviz_config`` (fixed frame odom, the robot model, TF, the
               reference and predicted paths, the odometry) where rviz2 is installed; where it is not, the
               launch says so in its log and runs without it (docs/howto/views.md)
rviz_config    the RViz view of ``rviz:=true`` (default: config/robotino.rviz)

The robot description (the URDF from the plant's parameters, `description.urdf.robotino_urdf`) is
published in realtime by robot_state_publisher where it is installed, else (and always in lockstep, where its
keep-all ``mode`` records every wheel transform; robot_state_publisher's /tf is keep-last) by the package's
``robot_description_publisher``. Every node gets ``OPENBLAS_NUM_THREADS=1`` (as `processes.NodeGroup`).

The scenario is resolved when the launch runs (an ``OpaqueFunction``): an unknown name, a bad namespace
or frame prefix stops the launch with a clear error. With ``record:=true`` the lockstep plant also waits for
the recorder's subscriptions (``lockstep_wait_for``), and the controller holds its answers until their topic
(the command's, with plans the plans') has matched the plant's and the recorder's readers
(``lockstep_command_readers``), so the recording holds tick 0 and the plant gets its answer. Without ``ros2 launch``,
``robotino-geom-mpc run`` starts the same processes and also writes metrics.json and the figures
from the recording.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, LogInfo, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import EnvironmentVariable, LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.specs import RECORDED_CONTROLLER_SPECS
from robotino_geom_mpc.description.urdf import check_frame_prefix, robotino_urdf
from robotino_geom_mpc.params.presets import config_file
from robotino_geom_mpc.system.processes import FASTDDS_PROFILE, FLEET_NODES, FRAME_PREFIX_NODES, LOCKSTEP_WAIT_FOR, \
    PROFILE_SETTLE_S, command_readers, fleet_realtime_parameters, fleet_wait_for, frame_prefix, namespace_remaps, \
    recorder_wait_for, robot_names, ros_namespace, scenario_parameters
from robotino_geom_mpc.system.launch_arguments import flag, node_environment, number

PACKAGE = "robotino_geom_mpc"


def _package_profile(path: str) -> bool:
    """Whether the Fast DDS profile `path` is the package's (`processes.FASTDDS_PROFILE`, by its contents)."""
    try:
        return bool(path) and Path(path).read_bytes() == config_file(FASTDDS_PROFILE).read_bytes()
    except OSError:  # no such file: Fast DDS reports it at the nodes' start
        return False


def _has_robot_state_publisher() -> bool:
    """Whether robot_state_publisher is installed (in the ament index)."""
    from ament_index_python.packages import get_package_share_directory

    try:
        get_package_share_directory("robot_state_publisher")
    except (LookupError, OSError):  # not in the index (PackageNotFoundError), or no index at all
        return False
    return True


def _rviz(config: dict, namespace: str, remappings: list) -> list:
    """rviz2 with the package's view where it is installed (the ament index), else a log line saying so."""
    from ament_index_python.packages import get_package_share_directory

    try:
        get_package_share_directory("rviz2")
    except (LookupError, OSError):  # not in the index (PackageNotFoundError), or no index at all
        return [LogInfo(msg="rviz:=true but rviz2 is not installed (apt install ros-jazzy-rviz2): running without "
                            f"it; open {config['rviz_config']} in rviz2 elsewhere, or the Foxglove layout")]
    return [Node(package="rviz2", executable="rviz2", name="rviz2", namespace=namespace, remappings=remappings,
                 arguments=["-d", config["rviz_config"]], output="screen")]


def _description(plant_params: str, prefix: str, mode: str, **common) -> Node:
    """The robot description publisher: in realtime robot_state_publisher if installed, else the package's own
    (with `mode`: lockstep makes its joint_states and /tf keep-all, robot_state_publisher's are keep-last).
    """
    if mode == "realtime" and _has_robot_state_publisher():
        robot, _ = load_params(plant_params)
        return Node(package="robot_state_publisher", executable="robot_state_publisher",
                    parameters=[{"robot_description": robotino_urdf(robot), "frame_prefix": prefix}], **common)
    return Node(package=PACKAGE, executable="robot_description_publisher",
                parameters=[plant_params, {"frame_prefix": prefix, "mode": mode}], **common)


def _nodes(context) -> list:
    """The nodes of the run, each with its scenario's overrides (`processes.scenario_parameters`), and the
    handler that shuts the launch down when the plant exits.
    """
    config = context.launch_configurations
    scenario, params_file = config["scenario"], config["params_file"]
    robot, control = load_params(params_file)
    buffer = flag(config, "command_buffer")
    # over a scenario's link: plans, as run; with the buffer the controller's plans go to it
    overrides, plans = scenario_parameters(scenario, robot, control, plans=True if buffer else None)
    lockstep = flag(config, "lockstep")
    mode = "lockstep" if lockstep else "realtime"
    record = flag(config, "record")
    namespace = ros_namespace(config["namespace"])
    prefix = frame_prefix(namespace) if config["frame_prefix"] == "auto" else check_frame_prefix(config["frame_prefix"])
    frames = {"frame_prefix": prefix}
    interface = config["command_interface"]
    if interface not in ("voltages", "cmd_vel"):
        raise ValueError(f"launch argument 'command_interface' must be voltages or cmd_vel, got {interface!r}")
    command = {} if interface == "voltages" else {"command_interface": interface}  # voltages: the nodes' default
    env = node_environment(config)
    remappings = [(old, new) for old, new in namespace_remaps(namespace, lockstep).items() if old != "__ns"]
    common = {"namespace": namespace, "remappings": remappings, "additional_env": env, "output": "screen"}

    robots = int(number(config, "robots", int))
    if robots and (namespace or config["frame_prefix"] != "auto" or buffer):
        raise ValueError("launch argument 'robots': a fleet's robots are robot1 .. robotN, each its namespace and "
                         "frame prefix (no 'namespace', 'frame_prefix' auto, no 'command_buffer')")
    linked = any(name.startswith("link.") for name in overrides["plant_node"])  # the scenario's radio link
    if buffer:  # the robot side of real_robot_buffer.md: the buffer drives the plant's cmd_vel from the plans
        if interface != "cmd_vel" or lockstep or linked:
            raise ValueError("launch argument 'command_buffer': the buffer takes the controller's cmd_vel plans on "
                             "the robot's clock (command_interface:=cmd_vel, lockstep:=false, a scenario without "
                             "a link)")
        del overrides["plant_node"]["plans"]  # the plant is the driver: the buffer's twists on cmd_vel
        overrides["controller_node"]["publish_plain_command"] = False  # else a second source on cmd_vel
    if robots and linked:
        raise ValueError(f"launch argument 'robots': a fleet runs without a link (scenario {scenario!r} has one), "
                         "as robotino-geom-mpc run --robots")

    def own(name: str) -> dict:  # the frame prefix for the nodes that declare it (a fleet's robots: their own)
        return frames if name in FRAME_PREFIX_NODES and not robots else {}

    def kind(name: str, node_name: str) -> dict:  # the executable: one robot's, or the fleet's (its nodes named)
        return {"executable": FLEET_NODES[name]} if robots else {"executable": name, "name": node_name}

    fleet = {"robots": robot_names(robots)} if robots else {}
    realtime_fleet = fleet_realtime_parameters(control.period_s) if robots and not lockstep else {}
    # the package's profile announces every 0.1 s: the lockstep plant settles one announcement, as under run
    settle = {"lockstep_settle_s": PROFILE_SETTLE_S} if lockstep and _package_profile(config["fastdds_profile"]) \
        else {}
    plant = {**overrides["plant_node"], "mode": mode, **settle, "duration_s": number(config, "duration"),
             "seed": number(config, "seed", int), **command, **own("plant_node"), **fleet}
    if robots:  # every robot's loop (and the recorder's) subscriptions, the fleet's /clock read by each robot's
        plant["lockstep_wait_for"] = fleet_wait_for(robots, record, interface)
    elif record:  # the lockstep plant also waits for the recorder's subscriptions
        plant["lockstep_wait_for"] = recorder_wait_for(interface, plans)
    else:  # the loop's subscriptions (the controller's preview one too), as under run
        plant["lockstep_wait_for"] = list(LOCKSTEP_WAIT_FOR)
    controller = {**overrides["controller_node"], **realtime_fleet.get("controller_node", {})}
    if lockstep:  # the command's readers the plant waits for, matched by the controller's writer too
        controller["lockstep_command_readers"] = command_readers(plant.get("lockstep_wait_for", ()), interface, plans)
    plant_node = Node(package=PACKAGE, **kind("plant_node", "robotino_plant"),
                      parameters=[config["plant_params"], plant], **common)
    nodes = [
        Node(package=PACKAGE, **kind("trajectory_node", "robotino_trajectory"),
             parameters=[params_file, {**overrides["trajectory_node"], "mode": mode, **own("trajectory_node"),
                                       **fleet, **realtime_fleet.get("trajectory_node", {})}],
             **common),
        Node(package=PACKAGE, **kind("controller_node", "robotino_controller"),
             parameters=[params_file, {**controller, "mode": mode, **command, **own("controller_node"), **fleet}],
             **common),
        plant_node,
        *([] if robots else [_description(config["plant_params"], prefix, mode, **common)]),
    ]
    if buffer:
        nodes.append(Node(package=PACKAGE, executable="command_buffer_node", name="robotino_command_buffer",
                          parameters=[params_file], **common))
    if record:  # it stores the controller's chain and loop settings given here (for the replays)
        settings = {spec.name: controller[spec.name] for spec in RECORDED_CONTROLLER_SPECS if spec.name in controller}
        nodes.append(Node(package=PACKAGE, executable="recorder_node", name="recorder",
                          parameters=[params_file, {"output": config["bag"], "scenario": scenario, **settings}],
                          **common))
    views = _rviz(config, namespace, remappings) if flag(config, "rviz") else []
    ended = EmitEvent(event=Shutdown(reason="the plant ended the run"))
    return [*nodes, *views, RegisterEventHandler(OnProcessExit(target_action=plant_node, on_exit=[ended]))]


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "robotino3.yaml"])
    default_profile = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "fastdds_localhost.xml"])
    default_rviz = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "robotino.rviz"])
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="paper-circle", description="scenario (scenarios.py)"),
        DeclareLaunchArgument("params_file", default_value=default_params, description="parameter file (/** section)"),
        DeclareLaunchArgument("plant_params", default_value=LaunchConfiguration("params_file"),
                              description="parameter file of the plant"),
        DeclareLaunchArgument("lockstep", default_value="false",
                              description="true: the plant drives /clock; false: real time (default)"),
        DeclareLaunchArgument("namespace", default_value="", description="ROS namespace of the robot's nodes"),
        DeclareLaunchArgument("frame_prefix", default_value="auto",
                              description="frame id prefix; auto: '<namespace>/' with a namespace, else none"),
        DeclareLaunchArgument("fastdds_profile",
                              default_value=EnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE",
                                                                default_value=default_profile),
                              description="Fast DDS profile of the nodes (default: $FASTRTPS_DEFAULT_PROFILES_FILE "
                              "if set, else config/fastdds_localhost.xml); empty: none set by the launch"),
        DeclareLaunchArgument("command_interface", default_value="voltages",
                              description="voltages: wheel_voltages to the drives; cmd_vel: a base_link Twist"),
        DeclareLaunchArgument("duration", default_value="0.0",
                              description="run length [s], 0: until stopped; the plant's exit ends the launch"),
        DeclareLaunchArgument("seed", default_value="0", description="seed of the odometry noise"),
        DeclareLaunchArgument("command_buffer", default_value="false",
                              description="the buffer variant: the robot-side command buffer turns the controller's "
                              "plans into the plant's cmd_vel (controller: plans, no plain command); needs "
                              "command_interface:=cmd_vel, realtime, a scenario without a link"),
        DeclareLaunchArgument("record", default_value="false", description="start the MCAP recorder"),
        DeclareLaunchArgument("bag", default_value="", description="recording directory"),
        DeclareLaunchArgument("robots", default_value="0",
                              description="N > 0: a fleet of N robots robot1 .. robotN, one process per node kind"),
        DeclareLaunchArgument("rviz", default_value="false",
                              description="true: also start rviz2 with rviz_config (a log line where not installed)"),
        DeclareLaunchArgument("rviz_config", default_value=default_rviz, description="the RViz view of rviz:=true"),
        OpaqueFunction(function=_nodes),
    ])
