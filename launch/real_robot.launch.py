"""Launch what runs on the laptop beside a real Robotino: trajectory and controller (optionally the recorder).

No plant simulator, no robot description: the robocup-logistics driver (``rto_node``, started on its own, see
docs/howto/real_robotino.md) publishes the odometry and takes the twists. The controller commands it by
``cmd_vel`` through the chain controller (``chain.active: enabled``) and starts DISABLED by default: it publishes
zero twist every tick until ``~/enable`` (std_srvs/SetBool) is called with true. The reference starts at that
enable, from where the robot stands (the trajectory's ``start_on_enable`` and ``anchor_to_robot``): until then it
holds the robot's pose at rest, then runs the scenario moved rigidly onto the robot's pose, from rest, with no
catch-up (a disable holds again; the next enable starts the scenario anew from where the robot then is).

    ros2 launch robotino_geom_mpc real_robot.launch.py chain_params:=my_chain/chain_params.yaml
    ros2 service call /robotino_controller/enable std_srvs/srv/SetBool '{data: true}'    # go
    ros2 service call /robotino_controller/enable std_srvs/srv/SetBool '{data: false}'   # stop: zero twist

Launch arguments
----------------
scenario       the reference (default paper-circle); a scenario that changes the simulated robot (model
               mismatch, odometry noise, a radio link: robustness, wifi) is refused: a real robot has its own
params_file    ROS 2 parameter file of the robot (default: config/robotino3_real.yaml: the Robotino 3 preset and
               the chain settings of the robocup-logistics preset, with the lines a lab edits marked)
chain_params   the controller's chain file that ``robotino-geom-mpc identify --ros --out DIR`` writes
               (DIR/chain_params.yaml), read after params_file; empty (default): the preset's chain settings
namespace      the driver's namespace (its launch argument ``namespace``; default none, as the driver's): every
               node runs in it and ``odom`` / ``cmd_vel`` are pinned to ``<namespace>/odom`` and
               ``<namespace>/cmd_vel``, the driver's topics (reliable, volatile, as its depth-10 endpoints)
frame_prefix   prefix of our frame ids (the reference's ``odom``); ``auto`` (default): ``<namespace>/`` with a
               namespace, else none. The controller reads the driver's odometry in any frame
start_enabled  false (default): the controller publishes zero twist until enabled; true: it tracks at once
start_on_enable  true (default): the reference starts (t = 0) when the controller is enabled, holding its start
               at rest until then; false: about a second after the controller and the odometry are up, enabled
               or not (the controller then catches up at the firmware's ramps at the enable)
anchor_to_robot  true (default): the scenario is moved rigidly onto the robot's pose at the start (paper-circle's
               centre 0.5 m to the robot's left); false: the scenario as defined in the driver's ``odom`` (from its
               origin: the controller drives the robot there first)
fastdds_profile  Fast DDS profile of the nodes (default: $FASTRTPS_DEFAULT_PROFILES_FILE if set, else
               config/fastdds_localhost.xml: the driver runs on this host too); empty: none set by the launch
record         true: also start the MCAP recorder (bag in ``bag``; ``robotino-geom-mpc report BAG`` afterwards)
nav2_params    Nav2's parameter file (empty, the default: no Nav2). Given: scenario ``goals``, and Nav2's
               planner_server, bt_navigator (the tree that replans at 1 Hz, without recovery behaviours) and
               waypoint_follower with a lifecycle_manager, this package's trajectory node serving their
               ``follow_path`` in place of controller_server (docs/howto/nav2.md; map_server and amcl are Nav2's
               localization launch)
bag            recording directory (default: rosbag2_<date> in the working directory)

Bad arguments (an unknown scenario, a simulation-only one, a bad namespace, a missing file) stop the launch
with a clear error before any node starts (an ``OpaqueFunction``). The controller checks its parameters as
any node does (`params.files.check_parameter_files` gives the same verdict offline).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import EnvironmentVariable, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from robotino_geom_mpc.description.urdf import check_frame_prefix
from robotino_geom_mpc.params.files import load_params, read_parameter_file
from robotino_geom_mpc.scenarios import ScenarioError, get_scenario, node_parameters
from robotino_geom_mpc.system.launch_arguments import NAV2_BEHAVIOR_TREE, NAV2_SERVERS, driver_remaps, flag, \
    node_environment
from robotino_geom_mpc.system.processes import FRAME_PREFIX_NODES, frame_prefix, ros_namespace

PACKAGE = "robotino_geom_mpc"
_CONTROLLER = "robotino_controller"  # the controller node's name: identify's chain file has its section


def _reference_only(name: str) -> None:
    """Refuse a scenario that changes the simulated robot rather than the reference."""
    scenario = get_scenario(name)
    if scenario.mismatch is not None or scenario.noise.position_m or scenario.noise.yaw_rad \
            or scenario.link is not None:
        raise ScenarioError(f"scenario {name!r} changes the simulated robot (model mismatch, odometry noise or a "
                            "radio link), not the reference: on a real robot use the scenario of its reference "
                            f"({scenario.reference!r})")


def _nodes(context) -> list:
    """Trajectory (started by the enable, at the robot, unless told otherwise), controller (disabled unless
    start_enabled) and the optional recorder.
    """
    config = context.launch_configurations
    scenario, params_file, chain_file = config["scenario"], config["params_file"], config["chain_params"]
    nav2_params = config["nav2_params"]
    if nav2_params:
        scenario = "goals"  # the trajectory node is then the follow_path server
    _reference_only(scenario)
    robot, _ = load_params(params_file)  # a missing or malformed file stops the launch here
    namespace = ros_namespace(config["namespace"])
    prefix = frame_prefix(namespace) if config["frame_prefix"] == "auto" else check_frame_prefix(config["frame_prefix"])
    common = {"namespace": namespace, "remappings": driver_remaps(namespace),
              "additional_env": node_environment(config), "output": "screen"}

    def own(name: str) -> dict:  # the frame prefix for the nodes that declare it
        return {"frame_prefix": prefix} if name in FRAME_PREFIX_NODES else {}

    controller = {"mode": "realtime", "command_interface": "cmd_vel", "chain.active": "enabled",
                  "start_enabled": flag(config, "start_enabled"), **own("controller_node")}
    trajectory = {**node_parameters(scenario, robot)["trajectory_node"], "mode": "realtime",
                  **{name: flag(config, name) for name in ("start_on_enable", "anchor_to_robot")},
                  **own("trajectory_node")}
    nodes = [
        Node(package=PACKAGE, executable="trajectory_node", name="robotino_trajectory",
             parameters=[params_file, trajectory], **common),
        Node(package=PACKAGE, executable="controller_node", name=_CONTROLLER,
             parameters=[params_file, *([chain_file] if chain_file else []), controller], **common),
    ]
    if flag(config, "record"):  # with the controller's chain.* (stored in the bag: regress replays them)
        chain = {name: value for name, value in (read_parameter_file(chain_file, _CONTROLLER).items()
                                                 if chain_file else ()) if name.startswith("chain.")}
        nodes.append(Node(package=PACKAGE, executable="recorder_node", name="recorder",
                          parameters=[params_file, {**chain, "chain.active": "enabled", "output": config["bag"],
                                                    "scenario": scenario}], **common))
    if nav2_params:
        nodes += _nav2(nav2_params, namespace)
    return nodes


def _nav2(params_file: str, namespace: str) -> list:
    """Nav2's servers but controller_server, and their lifecycle manager (`NAV2_SERVERS`)."""
    tree = {"default_nav_to_pose_bt_xml": PathJoinSubstitution([FindPackageShare(NAV2_BEHAVIOR_TREE[0]),
                                                                *NAV2_BEHAVIOR_TREE[1:]])}
    nodes = [Node(package=package, executable=executable, name=executable, namespace=namespace, output="screen",
                  parameters=[params_file, *([tree] if executable == "bt_navigator" else [])])
             for package, executable in NAV2_SERVERS]
    nodes.append(Node(package="nav2_lifecycle_manager", executable="lifecycle_manager",
                      name="lifecycle_manager_navigation", namespace=namespace, output="screen",
                      parameters=[{"autostart": True, "node_names": [name for _, name in NAV2_SERVERS]}]))
    return nodes


def generate_launch_description() -> LaunchDescription:
    default_params = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "robotino3_real.yaml"])
    default_profile = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "fastdds_localhost.xml"])
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="paper-circle", description="the reference (scenarios.py)"),
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="the robot's parameter file (default config/robotino3_real.yaml)"),
        DeclareLaunchArgument("chain_params", default_value="",
                              description="identify's DIR/chain_params.yaml (empty: the preset's chain)"),
        DeclareLaunchArgument("namespace", default_value="", description="the driver's namespace (default none)"),
        DeclareLaunchArgument("frame_prefix", default_value="auto",
                              description="frame id prefix; auto: '<namespace>/' with a namespace, else none"),
        DeclareLaunchArgument("start_enabled", default_value="false",
                              description="false: zero twist until ~/enable true; true: track at once"),
        DeclareLaunchArgument("start_on_enable", default_value="true",
                              description="true: the reference starts at the controller's enable, held until then"),
        DeclareLaunchArgument("anchor_to_robot", default_value="true",
                              description="true: the scenario starts at the robot's pose (moved rigidly onto it)"),
        DeclareLaunchArgument("fastdds_profile",
                              default_value=EnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE",
                                                                default_value=default_profile),
                              description="Fast DDS profile of the nodes; empty: none set by the launch"),
        DeclareLaunchArgument("record", default_value="false", description="start the MCAP recorder"),
        DeclareLaunchArgument("bag", default_value="", description="recording directory"),
        DeclareLaunchArgument("nav2_params", default_value="",
                              description="Nav2's parameter file: also start Nav2 (follow_path served here)"),
        OpaqueFunction(function=_nodes),
    ])
