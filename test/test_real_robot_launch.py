"""The launches for a real robot and the stand-in driver, read with the launch stand-ins (test/launch_standins.py).

launch/real_robot.launch.py (the laptop beside a real Robotino), launch/robot_side.launch.py (the robot's PC, the
command-buffer variant) and launch/driver_standin.launch.py (the emulated chain as the driver): which nodes
start (no simulator beside a real robot), with which parameters (checked as the nodes check them, in the files
launch_ros writes), in the driver's namespace and topics; config/robotino3_real.yaml against the preset and
the chain preset. That the stand-in drives like the robot and the page's commands work: test_real_robot_page.
"""

from pathlib import Path

import pytest

from robotino_geom_mpc.cli.identify import write_chain_file
from robotino_geom_mpc.model.driver_chain import CHAIN_PRESETS, chain_params
from robotino_geom_mpc.params.files import check_parameter_files, load_params, parse_parameter_file
from robotino_geom_mpc.params.specs import ParamError
from robotino_geom_mpc.scenarios import ScenarioError
from robotino_geom_mpc.system.processes import NamespaceError
from launch_standins import LAUNCH_DIR, REPO, Recorded, evaluate, install, launch_ros_file, load_description, of

pytestmark = pytest.mark.unit

REAL_PARAMS = REPO / "config" / "robotino3_real.yaml"
PRESET = REPO / "config" / "robotino3.yaml"


def _share(package: str) -> str:
    assert package == "robotino_geom_mpc", package  # the launches name no other package
    return str(REPO)


@pytest.fixture
def launch(monkeypatch):
    """``launch(file, **arguments)``: the nodes (by executable) the file starts, and the context."""
    install(monkeypatch.setitem)
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)  # the defaults as a user without one gets

    def evaluate_file(name: str, **arguments: str) -> tuple[dict[str, Recorded], object]:
        description = load_description(LAUNCH_DIR / name)
        actions, context = evaluate(description, arguments, _share)
        nodes = {n.kwargs["executable"]: n for n in of("Node", actions)}
        assert len(nodes) == len(actions)  # nothing but nodes (no shutdown handler: no plant ends these runs)
        declared = {a.args[0] for a in of("DeclareLaunchArgument", description)}
        assert context.launch_configurations.read <= declared
        return nodes, context

    return evaluate_file


def _files(node: Recorded, folder: Path) -> list[Path]:
    """The node's ``--params-file`` list as launch_ros gives it (its dicts written as launch_ros writes them)."""
    paths = []
    for i, entry in enumerate(node.kwargs["parameters"]):
        if isinstance(entry, dict):
            path = folder / f"{node.kwargs['executable']}_{i}.yaml"
            path.write_text(launch_ros_file(node, entry))
            entry = path
        paths.append(Path(entry))
    return paths


def test_the_robot_side_launch_starts_the_command_buffer_alone(launch):
    nodes, _ = launch("robot_side.launch.py")
    assert list(nodes) == ["command_buffer_node"]  # no plant_node (its odom beside the driver's), no controller
    buffer = nodes["command_buffer_node"]
    assert buffer.kwargs["parameters"] == [str(REAL_PARAMS)] and buffer.kwargs["namespace"] == ""
    assert buffer.kwargs["remappings"] == [("odom", "/odom"), ("cmd_vel", "/cmd_vel")]
    assert buffer.kwargs["additional_env"]["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(REPO / "config" / "fastdds_udp.xml")
    moved, _ = launch("robot_side.launch.py", namespace="robotinobase1")
    assert moved["command_buffer_node"].kwargs["namespace"] == "/robotinobase1"
    assert dict(moved["command_buffer_node"].kwargs["remappings"])["cmd_vel"] == "/robotinobase1/cmd_vel"


def test_the_real_robot_launch_starts_no_simulator_and_a_disabled_chain_controller(launch, tmp_path):
    nodes, _ = launch("real_robot.launch.py")
    assert set(nodes) == {"trajectory_node", "controller_node"}  # no plant_node, no robot description
    controller, trajectory = nodes["controller_node"], nodes["trajectory_node"]
    assert controller.kwargs["name"] == "robotino_controller"  # its ~/enable: /robotino_controller/enable
    files, overrides = controller.kwargs["parameters"]
    assert files == str(REAL_PARAMS)
    assert overrides == {"mode": "realtime", "command_interface": "cmd_vel", "chain.active": "enabled",
                         "start_enabled": False, "frame_prefix": ""}
    assert trajectory.kwargs["parameters"] == [str(REAL_PARAMS), {"scenario": "paper-circle", "mode": "realtime",
                                                                  "start_on_enable": True, "anchor_to_robot": True,
                                                                  "frame_prefix": ""}]
    for node in nodes.values():  # the driver's topics (its launch's default namespace: none)
        assert node.kwargs["namespace"] == ""
        assert node.kwargs["remappings"] == [("odom", "/odom"), ("cmd_vel", "/cmd_vel")]
        assert node.kwargs["additional_env"] == {"OPENBLAS_NUM_THREADS": "1", "FASTRTPS_DEFAULT_PROFILES_FILE": str(
            REPO / "config" / "fastdds_localhost.xml")}
    # what reaches the nodes passes their parameter check, and the controller runs the chain preset
    for node in nodes.values():
        check_parameter_files(_files(node, tmp_path))
    values = {}
    for path in _files(controller, tmp_path):
        for section, entries in parse_parameter_file(path).items():
            if section in ("/**", "robotino_controller", "/robotino_controller"):
                values.update(entries)
    assert {k: values[k] for k in CHAIN_PRESETS["robocup-logistics"]} == CHAIN_PRESETS["robocup-logistics"]
    assert values["start_enabled"] is False and values["chain.active"] == "enabled"


def test_identifys_chain_file_and_the_arguments_reach_the_nodes(launch, tmp_path):
    identified = chain_params({"chain.link.delay_s": 0.004, "chain.ramp_translation_m_s2": 0.55})
    chain_file = write_chain_file(tmp_path / "chain_params.yaml", {"chain.active": "enabled",
                                                                   **identified.values()}, "identify")
    nodes, _ = launch("real_robot.launch.py", chain_params=str(chain_file), start_enabled="true",
                      namespace="robotinobase1", record="true", bag=str(tmp_path / "bag"), scenario="lemniscate",
                      start_on_enable="false", anchor_to_robot="0")
    assert set(nodes) == {"trajectory_node", "controller_node", "recorder_node"}
    controller = nodes["controller_node"]
    files = controller.kwargs["parameters"]
    assert files[:2] == [str(REAL_PARAMS), str(chain_file)]  # identify's values win over the file's preset
    assert files[2]["start_enabled"] is True and files[2]["frame_prefix"] == "robotinobase1/"
    trajectory = nodes["trajectory_node"].kwargs["parameters"][1]
    assert trajectory["scenario"] == "lemniscate"
    assert trajectory["start_on_enable"] is False and trajectory["anchor_to_robot"] is False
    # the recorder stores the controller's chain (identify's) with the run: regress replays it from the bag
    assert nodes["recorder_node"].kwargs["parameters"][1] == {
        **identified.values(), "chain.active": "enabled", "output": str(tmp_path / "bag"), "scenario": "lemniscate"}
    for node in nodes.values():
        assert node.kwargs["namespace"] == "/robotinobase1"
        assert node.kwargs["remappings"] == [("odom", "/robotinobase1/odom"), ("cmd_vel", "/robotinobase1/cmd_vel")]
        check_parameter_files(_files(node, tmp_path))
    values = {}
    for path in _files(controller, tmp_path):
        for entries in parse_parameter_file(path).values():
            values.update(entries)
    assert values["chain.link.delay_s"] == 0.004 and values["chain.ramp_translation_m_s2"] == 0.55


@pytest.mark.parametrize("arguments, error, match", [
    ({"scenario": "robustness"}, ScenarioError, "changes the simulated robot.*'paper-circle'"),
    ({"scenario": "wifi"}, ScenarioError, "radio link"),
    ({"scenario": "paper-circel"}, ScenarioError, "did you mean 'paper-circle'"),
    ({"start_enabled": "yes"}, ValueError, "start_enabled"),
    ({"start_on_enable": "on"}, ValueError, "start_on_enable"),
    ({"anchor_to_robot": ""}, ValueError, "anchor_to_robot"),
    ({"record": "maybe"}, ValueError, "record"),
    ({"namespace": "robot-1"}, NamespaceError, "robot-1"),
    ({"params_file": "/nonexistent/robot.yaml"}, (OSError, ParamError), "robot.yaml"),
])
def test_bad_arguments_stop_the_real_robot_launch(launch, arguments, error, match):
    with pytest.raises(error, match=match):
        launch("real_robot.launch.py", **arguments)


def test_the_standin_runs_the_emulated_chain_under_the_drivers_names(launch):
    nodes, _ = launch("driver_standin.launch.py", hostname="172.26.1.1:12080", launch_joynode="false")
    assert list(nodes) == ["plant_node"]
    plant = nodes["plant_node"]
    assert plant.kwargs["name"] == "robotino_node" and plant.kwargs["namespace"] == ""
    files, overrides = plant.kwargs["parameters"]
    assert files == str(PRESET)
    assert overrides["chain.active"] == "enabled" and overrides["command_interface"] == "cmd_vel"
    assert overrides["mode"] == "realtime" and overrides["duration_s"] == 0.0 and overrides["publish_tf"] is False
    assert {k: overrides[k] for k in CHAIN_PRESETS["robocup-logistics"]} == CHAIN_PRESETS["robocup-logistics"]
    remaps = dict(plant.kwargs["remappings"])
    assert remaps["odom"] == "/odom" and remaps["cmd_vel"] == "/cmd_vel"
    # no topic a recording or report would take for the robot's truth (hidden: a leading underscore)
    assert remaps["ground_truth/odom"] == "/_standin/ground_truth/odom"
    assert remaps["wheel_currents"] == "/_standin/wheel_currents"
    assert remaps["applied_voltages"] == "/_standin/applied_voltages"
    moved, _ = launch("driver_standin.launch.py", namespace="robotinobase1")
    truth = dict(moved["plant_node"].kwargs["remappings"])["ground_truth/odom"]
    assert truth == "/robotinobase1/_standin/ground_truth/odom"


def test_the_real_parameter_file_is_the_preset_robot_and_the_chain_preset():
    """config/robotino3_real.yaml: the Robotino 3 preset's robot and controller settings, the robocup-logistics
    chain for the controller, the lines a lab edits marked; it passes the nodes' check alone and under identify's
    file.
    """
    check_parameter_files([REAL_PARAMS])
    assert load_params(REAL_PARAMS) == load_params(PRESET)
    sections = parse_parameter_file(REAL_PARAMS)
    assert set(sections) == {"/**", "robotino_controller"}
    controller = sections["robotino_controller"]
    assert controller["chain.active"] == "enabled" and controller["command_interface"] == "cmd_vel"
    assert {k: controller[k] for k in CHAIN_PRESETS["robocup-logistics"]} == CHAIN_PRESETS["robocup-logistics"]
    marked = [line.split(":")[0].strip() for line in REAL_PARAMS.read_text().splitlines() if "# LAB:" in line]
    assert marked == ["mass_kg", "wheel_radius_m", "wheel_distance_m", "speed_floor", "speed_floor_translation_m_s",
                      "speed_floor_rotation_rad_s"]


def test_nav2_params_start_nav2_with_the_trajectory_node_in_controller_servers_place(launch, tmp_path):
    nav2 = tmp_path / "nav2_params.yaml"
    nav2.write_text("planner_server:\n  ros__parameters:\n    expected_planner_frequency: 1.0\n")
    nodes, _ = launch("real_robot.launch.py", nav2_params=str(nav2), namespace="robotinobase1")
    assert set(nodes) == {"trajectory_node", "controller_node", "planner_server", "bt_navigator",
                          "waypoint_follower", "lifecycle_manager"}  # no controller_server, no simulator
    trajectory = nodes["trajectory_node"].kwargs["parameters"][1]
    assert trajectory["scenario"] == "goals"  # the follow_path server
    manager = nodes["lifecycle_manager"].kwargs["parameters"][0]
    assert manager["node_names"] == ["planner_server", "bt_navigator", "waypoint_follower"] and manager["autostart"]
    for name in ("planner_server", "bt_navigator", "waypoint_follower", "lifecycle_manager"):
        assert nodes[name].kwargs["namespace"] == "/robotinobase1"  # beside the robot's nodes and action
    assert nodes["planner_server"].kwargs["parameters"] == [str(nav2)]
    tree = nodes["bt_navigator"].kwargs["parameters"][1]["default_nav_to_pose_bt_xml"]
    package = tree.args[0][0]
    assert package.args == ("nav2_bt_navigator",) and tree.args[0][1:] == ["behavior_trees",
                                                                            "navigate_w_replanning_time.xml"]
    without, _ = launch("real_robot.launch.py")
    assert set(without) == {"trajectory_node", "controller_node"}


def test_the_nav2_example_parameters_configure_what_the_launch_starts():
    import yaml

    from robotino_geom_mpc.description.urdf import BASE_RADIUS_M
    from robotino_geom_mpc.system.launch_arguments import NAV2_SERVERS

    sections = yaml.safe_load((REPO / "config" / "nav2_robotino.yaml").read_text())
    assert set(sections) == {name for _, name in NAV2_SERVERS} | {"global_costmap"}  # no controller_server
    costmap = sections["global_costmap"]["global_costmap"]["ros__parameters"]
    assert costmap["robot_radius"] == BASE_RADIUS_M
    assert costmap["global_frame"] == sections["bt_navigator"]["ros__parameters"]["global_frame"] == "map"
    assert "follow_path_error_code" in sections["bt_navigator"]["ros__parameters"]["error_code_names"]
