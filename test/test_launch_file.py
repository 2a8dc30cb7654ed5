"""The launch file's description, built with stand-ins for `launch` and `launch_ros` (neither is on PyPI).

The stand-ins record what the file passes to each action, and its `OpaqueFunction` is evaluated with a
context whose launch configurations the test sets, so the test checks the file's own logic only: which nodes
start, with which parameters for each scenario (against `scenarios.node_parameters` and against the
models `simulation.run_scenario` uses offline), the namespace, remappings and frame prefix of every node
(against `processes.node_arguments`, the arguments `run` gives its processes), the nodes' environment
(Fast DDS profile, one BLAS thread), the robot description publisher, and that every launch configuration
it reads is a declared argument. (That it compiles and names installed files: test_colcon_build.)

What the stand-ins cannot show (launch_ros's handling of the actions, the processes it starts, their
shutdown) was run by hand with the real launch 3.4.3 and launch_ros 0.26.6 (docs/howto/launch.md); what
reaches the nodes from it is pinned through files: the parameter files launch_ros wrote in two real
launches (test/data/launch_ros), which an emulation of its writer reproduces byte for byte, and the
emulated files of every configuration pass each node's parameter-file check.
"""

import itertools
import json
from pathlib import Path

import pytest
import yaml

import ament_index_python.packages

from robotino_geom_mpc.params.files import check_parameter_files, load_params, parse_parameter_file, \
    read_parameter_file
from robotino_geom_mpc.params.presets import config_file, default_params_file
from robotino_geom_mpc.params.specs import ALL_SPECS, params_from_values
from robotino_geom_mpc.description.urdf import DescriptionError, robotino_urdf
from robotino_geom_mpc.system.processes import FRAME_PREFIX_NODES, LOCKSTEP_WAIT_FOR, RECORDER_WAIT_FOR, \
    NamespaceError, node_arguments, recorder_wait_for
from robotino_geom_mpc.scenarios import SCENARIOS, ScenarioError, get_scenario, node_parameters
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController
from launch_standins import Context, Recorded, install, launch_ros_file, load_description, of

pytestmark = pytest.mark.unit

LAUNCH_FILE = Path(__file__).resolve().parents[1] / "launch" / "robotino_geom_mpc.launch.py"
PARAMS = str(default_params_file())
PROFILE = str(config_file("fastdds_localhost.xml"))
RVIZ = str(config_file("robotino.rviz"))
LOOP = {"trajectory_node", "controller_node", "plant_node"}
DESCRIPTION = "robot_description_publisher"  # the package's own, where robot_state_publisher is not installed


@pytest.fixture
def description(monkeypatch):
    """The launch description, with robot_state_publisher not installed (see `with_rsp`)."""
    monkeypatch.setattr(ament_index_python.packages, "get_package_share_directory", _not_installed)
    install(monkeypatch.setitem)
    return load_description(LAUNCH_FILE)


def _not_installed(package: str) -> str:
    raise ament_index_python.packages.PackageNotFoundError(package)


_of = of


def _defaults(description) -> dict[str, str]:
    """The declared arguments' defaults, as launch would perform them (the file paths set here; the profile
    as without FASTRTPS_DEFAULT_PROFILES_FILE in the environment).
    """
    files = {"params_file": PARAMS, "plant_params": PARAMS, "fastdds_profile": PROFILE, "rviz_config": RVIZ}
    values = {a.args[0]: a.kwargs["default_value"] for a in _of("DeclareLaunchArgument", description)}
    assert all(isinstance(v, str) for k, v in values.items() if k not in files)
    return {**values, **files}


def _launch(description, **arguments: str) -> tuple[dict[str, Recorded], Context]:
    """Evaluate the file's OpaqueFunction with `arguments` over the defaults: nodes by executable, context."""
    (opaque,) = _of("OpaqueFunction", description)
    context = Context({**_defaults(description), **arguments})
    actions = opaque.kwargs["function"](context)
    nodes = {n.kwargs["executable"]: n for n in _of("Node", actions)}
    assert len(nodes) == len(actions) - 1  # and the handler of the plant's exit (`test_the_plants_exit_ends_...`)
    return nodes, context


def _overrides(node: Recorded) -> dict:
    """A node's parameter overrides: the dict after its parameter file."""
    files, overrides = node.kwargs["parameters"]
    assert files == PARAMS
    return overrides


def test_every_launch_configuration_read_is_a_declared_argument(description):
    declared = {a.args[0] for a in _of("DeclareLaunchArgument", description)}
    _, context = _launch(description, record="true")
    read = {c.args[0] for c in _of("LaunchConfiguration", Recorded.made)} | context.launch_configurations.read
    assert read <= declared and {"scenario", "lockstep", "record", "bag", "seed", "duration", "namespace",
                                 "frame_prefix", "fastdds_profile", "command_interface"} <= read


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_each_node_gets_its_scenarios_parameters(description, scenario):
    robot, control = load_params(PARAMS)
    nodes, _ = _launch(description, scenario=scenario, duration="2.5", seed="7", lockstep="true")
    assert set(nodes) == LOOP | {DESCRIPTION}
    by_node = {name: _overrides(nodes[name]) for name in LOOP}
    want = node_parameters(scenario, robot)
    for name, node_overrides in by_node.items():
        assert node_overrides["mode"] == "lockstep"
        assert {k: v for k, v in node_overrides.items() if k in want[name]} == want[name]
    assert nodes[DESCRIPTION].kwargs["parameters"][1]["mode"] == "lockstep"  # its joint_states and /tf keep-all
    offline = run_scenario(RunConfig(scenario, robot, control, duration_s=0.05))
    # over a link: plans, as the offline run compensates the link (the preview as long as the plans need)
    plans = "link" in offline.meta and offline.meta["link"]["compensated"]
    assert [by_node[name].get("plans", False) for name in ("controller_node", "plant_node")] == [plans, plans]
    longer = {"preview_points": DelayCompensatingController(robot, control).preview_length} if plans else {}
    assert {k: v for k, v in by_node["trajectory_node"].items() if k != "frame_prefix"} == \
        {"scenario": scenario, "mode": "lockstep", **longer}
    plant = by_node["plant_node"]
    assert plant["duration_s"] == 2.5 and plant["seed"] == 7 and plant["lockstep_wait_for"] == list(LOCKSTEP_WAIT_FOR)

    # independently: the controller's parameters (file plus overrides, read as the node reads them) are the
    # model the offline loop gives its controller, and the plant's noise is the offline run's
    values = {**read_parameter_file(PARAMS), **by_node["controller_node"]}
    launched, _ = params_from_values({s.name: values[s.name] for s in ALL_SPECS}, "launch")
    assert launched == get_scenario(scenario).controller_model(robot)
    assert [plant["odometry_noise.position_m"], plant["odometry_noise.yaw_rad"]] == offline.meta["odometry_noise"]
    assert (launched != robot) == (offline.meta["controller_mismatch"] is not None)


def test_robustness_gives_the_controller_a_mismatched_model_and_the_plant_noise(description):
    """The bug this file had: scenario:=robustness ran the nominal loop. Numbers from the paper's study."""
    robot, _ = load_params(PARAMS)
    nodes, _ = _launch(description, scenario="robustness")
    controller, plant = _overrides(nodes["controller_node"]), _overrides(nodes["plant_node"])
    assert controller["robot.mass_kg"] == pytest.approx(1.2 * robot.mass_kg)
    assert controller["robot.yaw_inertia_kg_m2"] == pytest.approx(0.8 * robot.yaw_inertia_kg_m2)
    assert controller["robot.body_friction_x_n_s_per_m"] == pytest.approx(2.0 * robot.body_friction_x_n_s_per_m)
    assert plant["odometry_noise.position_m"] == 1e-3 and plant["odometry_noise.yaw_rad"] == 1e-3
    nominal, _ = _launch(description, scenario="paper-circle")
    assert {k: v for k, v in _overrides(nominal["controller_node"]).items() if k != "frame_prefix"} == \
        {"mode": "realtime"}
    assert _overrides(nominal["plant_node"])["odometry_noise.position_m"] == 0.0


def test_with_record_the_recorder_starts_and_the_plant_waits_for_its_subscriptions(description):
    plain, _ = _launch(description, record="false", lockstep="false")
    assert "recorder_node" not in plain and _overrides(plain["plant_node"])["mode"] == "realtime"
    recorded, _ = _launch(description, record="True", bag="/tmp/some_bag", scenario="lemniscate")
    assert _overrides(recorded["recorder_node"]) == {"output": "/tmp/some_bag", "scenario": "lemniscate"}
    waiting = _overrides(recorded["plant_node"])
    assert waiting["lockstep_wait_for"] == recorder_wait_for() != list(RECORDER_WAIT_FOR)  # + the description publisher
    assert _overrides(plain["plant_node"])["lockstep_wait_for"] == list(LOCKSTEP_WAIT_FOR)  # the loop's nodes
    assert waiting.keys() == _overrides(plain["plant_node"]).keys()
    # the lockstep controller holds its first answer until its command matched the plant's and the recorder's
    # readers (the count the plant waits for), one reader without the recorder, nothing in realtime
    assert "lockstep_command_readers" not in _overrides(recorded["controller_node"])  # realtime
    lockstep, _ = _launch(description, record="true", bag="/tmp/b", lockstep="true")
    assert _overrides(lockstep["controller_node"])["lockstep_command_readers"] == 2
    alone, _ = _launch(description, record="false", lockstep="true")
    assert _overrides(alone["controller_node"])["lockstep_command_readers"] == 1
    assert "lockstep_command_readers" not in _overrides(plain["controller_node"])
    twist, _ = _launch(description, record="true", bag="/tmp/b", lockstep="true", command_interface="cmd_vel")
    assert _overrides(twist["controller_node"])["lockstep_command_readers"] == 2


@pytest.mark.parametrize("arguments, error, match", [
    ({"scenario": "robustnes"}, ScenarioError, "did you mean 'robustness'"),
    ({"scenario": "spiral"}, ScenarioError, "unknown scenario 'spiral'"),
    ({"lockstep": "yes"}, ValueError, "lockstep"),
    ({"duration": "-1"}, ValueError, "duration"),
    ({"seed": "1.5"}, ValueError, "seed"),
    ({"namespace": "robot-1"}, NamespaceError, "robot-1"),
    ({"frame_prefix": "/robot1"}, DescriptionError, "/robot1"),
    ({"command_interface": "twist"}, ValueError, "command_interface"),
    ({"robots": "2", "namespace": "team"}, ValueError, "robots"),
    ({"robots": "-2"}, ValueError, "robots"),
])
def test_bad_arguments_stop_the_launch_with_a_clear_error(description, arguments, error, match):
    with pytest.raises(error, match=match):
        _launch(description, **arguments)


def _ros_args_remaps(argv: list[str]) -> dict[str, str]:
    """The ``-r from:=to`` pairs of a node's ``--ros-args``."""
    return dict(argv[i + 1].split(":=", 1) for i, a in enumerate(argv) if a == "-r")


def _ros_args_parameter(argv: list[str], name: str) -> str | None:
    """The last ``-p name:=value`` of a node's ``--ros-args`` (the value as text), None without one."""
    values = [argv[i + 1].split(":=", 1)[1] for i, a in enumerate(argv) if a == "-p"
              and argv[i + 1].startswith(name + ":=")]
    return values[-1] if values else None


def test_people_get_realtime_the_fast_dds_profile_and_one_blas_thread_by_default(description):
    nodes, _ = _launch(description)
    assert _overrides(nodes["plant_node"])["mode"] == "realtime"
    for name, node in nodes.items():
        assert node.kwargs["additional_env"] == {"OPENBLAS_NUM_THREADS": "1", "FASTRTPS_DEFAULT_PROFILES_FILE": PROFILE}
        assert node.kwargs["namespace"] == "" and node.kwargs["remappings"] == [], name
    assert _overrides(nodes["plant_node"])["frame_prefix"] == ""
    custom, _ = _launch(description, fastdds_profile="/etc/robotino/udp.xml")
    assert custom["plant_node"].kwargs["additional_env"]["FASTRTPS_DEFAULT_PROFILES_FILE"] == "/etc/robotino/udp.xml"
    inherited, _ = _launch(description, fastdds_profile="")  # the environment's profile, if any
    assert all(n.kwargs["additional_env"] == {"OPENBLAS_NUM_THREADS": "1"} for n in inherited.values())


@pytest.mark.parametrize("lockstep", ["true", "false"])
def test_namespace_moves_every_node_as_run_does(description, lockstep):
    """Namespace, remappings and frame prefix of each node equal those of `node_arguments` (what `run` starts)."""
    nodes, _ = _launch(description, namespace="robot1", lockstep=lockstep, record="true", bag="/tmp/b")
    args = node_arguments("paper-circle", PARAMS, 0.0, lockstep == "true", bag="/tmp/b", namespace="robot1")
    for name, node in nodes.items():
        assert node.kwargs["namespace"] == "/robot1", name
        launched = {"__ns": node.kwargs["namespace"], **dict(node.kwargs["remappings"])}
        want = {"__ns": "/robot1", **({"/clock": "/robot1/clock"} if lockstep == "true" else {})}
        assert launched == want, name
        if name in args:
            assert _ros_args_remaps(args[name]) == launched, name
    for name in LOOP | {"recorder_node"}:
        got = _overrides(nodes[name]).get("frame_prefix")
        want = "robot1/" if name in FRAME_PREFIX_NODES else None
        assert got == _ros_args_parameter(args[name], "frame_prefix") == want, name
    files, description_overrides = nodes[DESCRIPTION].kwargs["parameters"]
    mode = "lockstep" if lockstep == "true" else "realtime"
    assert files == PARAMS and description_overrides == {"frame_prefix": "robot1/", "mode": mode}
    assert _ros_args_parameter(args[DESCRIPTION], "mode") == mode  # as `run` gives it


def test_an_explicit_frame_prefix_wins(description):
    nodes, _ = _launch(description, namespace="robot1", frame_prefix="left/")
    assert _overrides(nodes["plant_node"])["frame_prefix"] == "left/"
    assert nodes[DESCRIPTION].kwargs["parameters"][1] == {"frame_prefix": "left/", "mode": "realtime"}
    none, _ = _launch(description, namespace="robot1", frame_prefix="")
    assert _overrides(none["plant_node"])["frame_prefix"] == ""


def test_robot_state_publisher_publishes_the_plants_urdf_where_installed(description, monkeypatch, tmp_path):
    monkeypatch.setattr(ament_index_python.packages, "get_package_share_directory", lambda package: str(tmp_path))
    nodes, _ = _launch(description, namespace="robot2")
    assert DESCRIPTION not in nodes
    rsp = nodes["robot_state_publisher"]
    assert rsp.kwargs["package"] == "robot_state_publisher" and rsp.kwargs["namespace"] == "/robot2"
    robot, _ = load_params(PARAMS)
    assert rsp.kwargs["parameters"] == [{"robot_description": robotino_urdf(robot), "frame_prefix": "robot2/"}]
    lockstep, _ = _launch(description, namespace="robot2", lockstep="true")  # the package's: lossless /tf
    assert "robot_state_publisher" not in lockstep
    assert lockstep[DESCRIPTION].kwargs["parameters"][1] == {"frame_prefix": "robot2/", "mode": "lockstep"}


@pytest.mark.parametrize("interface", ["voltages", "cmd_vel"])
def test_command_interface_reaches_controller_and_plant_as_run_gives_it(description, interface):
    """command_interface (and, recorded, the plant's lockstep_wait_for) as `node_arguments` passes them to `run`'s
    processes: cmd_vel to the controller and the plant, voltages left to their default.
    """
    nodes, _ = _launch(description, command_interface=interface, lockstep="true", record="true", bag="/tmp/b")
    args = node_arguments("paper-circle", PARAMS, 0.0, True, bag="/tmp/b", command_interface=interface)
    for name in LOOP | {"recorder_node"}:
        got = _overrides(nodes[name]).get("command_interface")
        assert got == _ros_args_parameter(args[name], "command_interface"), name
        assert got == (interface if name in ("controller_node", "plant_node") and interface == "cmd_vel" else None)
    waiting = _overrides(nodes["plant_node"])["lockstep_wait_for"]
    assert waiting == json.loads(_ros_args_parameter(args["plant_node"], "lockstep_wait_for"))
    assert (f"{'cmd_vel' if interface == 'cmd_vel' else 'wheel_voltages'}:2") in waiting
    default, _ = _launch(description)
    assert all("command_interface" not in _overrides(default[name]) for name in LOOP)


def test_the_plants_exit_ends_the_launch(description):
    """The plant ends the run (its duration): launch then shuts the other nodes down, as `run` stops them."""
    opaque, = _of("OpaqueFunction", description)
    actions = opaque.kwargs["function"](Context({**_defaults(description), "duration": "20"}))
    (handler,) = _of("RegisterEventHandler", actions)
    (on_exit,) = handler.args
    assert type(on_exit).__name__ == "OnProcessExit"
    assert on_exit.kwargs["target_action"].kwargs["executable"] == "plant_node"
    (emit,) = on_exit.kwargs["on_exit"]
    assert type(emit).__name__ == "EmitEvent" and type(emit.kwargs["event"]).__name__ == "Shutdown"


def test_the_profile_default_is_the_environments_then_the_packages(description):
    """A user's FASTRTPS_DEFAULT_PROFILES_FILE (the UDP profile, a discovery server) is kept by default."""
    (profile,) = [a for a in _of("DeclareLaunchArgument", description) if a.args[0] == "fastdds_profile"]
    default = profile.kwargs["default_value"]
    assert type(default).__name__ == "EnvironmentVariable" and default.args == ("FASTRTPS_DEFAULT_PROFILES_FILE",)
    package = default.kwargs["default_value"]
    assert type(package).__name__ == "PathJoinSubstitution" and package.args[0][1:] == ["config",
                                                                                         "fastdds_localhost.xml"]


# --- the parameter files launch_ros writes for the file's dicts ------------------------------------------------
LAUNCH_ROS_FILES = Path(__file__).resolve().parent / "data" / "launch_ros"
# the arguments of the real launches whose files test/data/launch_ros keeps (launch 3.4.3, launch_ros 0.26.6)
FIXTURE_ARGUMENTS = {
    "robustness_lockstep_record": {"scenario": "robustness", "lockstep": "true", "record": "true", "duration": "8.0",
                                   "bag": "/tmp/ros27_src/runs/loopbag"},
    "robot1_cmd_vel_realtime_record": {"namespace": "robot1", "command_interface": "cmd_vel", "record": "true",
                                       "duration": "3.0", "bag": "/tmp/ros27_src/runs/bag_rt_ns"},
}


_launch_ros_file = launch_ros_file


def _written(nodes: dict[str, Recorded], folder: Path) -> dict[str, list[Path]]:
    """Each node's ``--params-file`` list as launch_ros gives it: its files, its dicts written as launch_ros does."""
    files = {}
    for executable, node in nodes.items():
        files[executable] = []
        for i, entry in enumerate(node.kwargs["parameters"]):
            if isinstance(entry, dict):
                path = folder / f"{executable}_{i}.yaml"
                path.write_text(_launch_ros_file(node, entry))
                entry = path
            files[executable].append(Path(entry))
    return files


@pytest.mark.parametrize("case", list(FIXTURE_ARGUMENTS))
def test_the_files_launch_ros_writes_are_those_it_wrote_in_a_real_launch(description, case, tmp_path):
    """The emulated writer against the files launch_ros 0.26.6 wrote (kept in test/data/launch_ros): the same
    bytes, ``!!python/tuple`` included; so the next test checks the form a real launch gives the nodes.
    """
    nodes, _ = _launch(description, **FIXTURE_ARGUMENTS[case])
    written = _written(nodes, tmp_path)
    for executable in nodes:
        real = (LAUNCH_ROS_FILES / case / f"{executable}.yaml").read_text()
        assert written[executable][-1].read_text() == real, executable
    assert "!!python/tuple" in (LAUNCH_ROS_FILES / case / "plant_node.yaml").read_text()


@pytest.mark.parametrize("lockstep, record, interface", [
    ("true", "true", "voltages"), ("true", "true", "cmd_vel"), ("false", "true", "voltages"),
    ("true", "false", "voltages"),
])
@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_every_node_accepts_the_files_launch_ros_gives_it(description, tmp_path, scenario, lockstep, record, interface):
    """The bug of issue 27: a recorded lockstep launch gave the plant a ``!!python/tuple`` its pre-check refused.
    Each node's files, as launch_ros writes them, pass the pre-check it makes before rclpy.init; the plant reads
    ``lockstep_wait_for`` from them as the list the file meant.
    """
    nodes, _ = _launch(description, scenario=scenario, lockstep=lockstep, record=record, command_interface=interface,
                       namespace="robot1" if interface == "cmd_vel" else "", bag="/tmp/bag")
    written = _written(nodes, tmp_path)
    for files in written.values():
        check_parameter_files(files)
    (values,) = parse_parameter_file(written["plant_node"][-1]).values()
    plans = get_scenario(scenario).link is not None  # over a link the plant reads plans (and the recorder)
    assert values["lockstep_wait_for"] == (recorder_wait_for(interface, plans) if record == "true"
                                           else list(LOCKSTEP_WAIT_FOR))


def test_command_buffer_runs_the_buffer_variant_the_buffer_the_only_cmd_vel_source(description):
    """``command_buffer:=true``: the controller sends plans and no plain command (a second source beside the
    buffer's on the driver's cmd_vel), the trajectory the plans' preview, the plant takes cmd_vel without plans
    (it is the driver); a configuration the buffer cannot serve stops the launch (its closed loop over DDS:
    test_command_buffer_node).
    """
    robot, control = load_params(PARAMS)
    nodes, _ = _launch(description, command_buffer="true", command_interface="cmd_vel")
    assert "command_buffer_node" in nodes
    controller, plant = _overrides(nodes["controller_node"]), _overrides(nodes["plant_node"])
    assert controller["plans"] is True and controller["publish_plain_command"] is False
    assert controller["command_interface"] == plant["command_interface"] == "cmd_vel" and "plans" not in plant
    assert _overrides(nodes["trajectory_node"])["preview_points"] == \
        DelayCompensatingController(robot, control).preview_length
    for arguments in ({}, {"command_interface": "cmd_vel", "lockstep": "true"},
                      {"command_interface": "cmd_vel", "scenario": "wifi"}):
        with pytest.raises(ValueError, match="command_buffer"):
            _launch(description, command_buffer="true", **arguments)


def _run_parameters(argv: list[str]) -> dict:
    """The ``-p name:=value`` of a node's `node_arguments` argv, each value read as YAML (as rcl reads it)."""
    return {name: yaml.safe_load(value) for flag, arg in zip(argv, argv[1:]) if flag == "-p"
            for name, _, value in [arg.partition(":=")]}


@pytest.mark.parametrize("layout", ["", "robot1", "fleet"])
@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_the_launch_gives_each_node_the_parameters_run_gives_it(description, scenario, layout):
    """For every scenario, mode, recording and command interface, one robot (without and with a namespace) or a
    fleet of two: each node's parameters from the launch file are those `run` gives it (`node_arguments`,
    `fleet_arguments`, with the package's Fast DDS profile), but for two defaults the launch leaves to the node
    or states itself (``odometry_model`` ideal; ``frame_prefix`` '' without a namespace). A fleet over a link is
    refused as ``run --robots`` refuses it.
    """
    from robotino_geom_mpc.model.encoders import ODOMETRY_DEFAULTS
    from robotino_geom_mpc.system.processes import fleet_arguments

    defaults = {"odometry_model": ODOMETRY_DEFAULTS["odometry_model"], "frame_prefix": ""}  # the nodes' defaults
    for lockstep, record, interface in itertools.product((True, False), (True, False), ("voltages", "cmd_vel")):
        arguments = {"scenario": scenario, "lockstep": str(lockstep).lower(), "record": str(record).lower(),
                     "bag": "/tmp/b", "command_interface": interface, "duration": "5.0", "seed": "3"}
        bag = "/tmp/b" if record else None
        if layout == "fleet":
            if get_scenario(scenario).link is not None:
                with pytest.raises(ValueError, match="without a link"):
                    _launch(description, **arguments, robots="2")
                continue
            launched, _ = _launch(description, **arguments, robots="2")
            run = fleet_arguments(scenario, PARAMS, 5.0, lockstep, 2, 3, bag, command_interface=interface, environ={})
        else:
            launched, _ = _launch(description, **arguments, namespace=layout)
            run = node_arguments(scenario, PARAMS, 5.0, lockstep, 3, bag, command_interface=interface,
                                 namespace=layout, environ={})
        assert set(launched) == set(run), arguments
        for executable, node in launched.items():
            got = {k: list(v) if isinstance(v, tuple) else v for k, v in _overrides(node).items()}
            want = _run_parameters(run[executable])
            for name, value in defaults.items():  # left out on one side: the node's default
                got.setdefault(name, value)
                want.setdefault(name, value)
            assert got == want, (executable, arguments)


def test_rviz_starts_rviz2_with_the_packages_view_where_installed_and_says_so_where_not(description, monkeypatch,
                                                                                      tmp_path):
    opaque, = _of("OpaqueFunction", description)
    missing = opaque.kwargs["function"](Context({**_defaults(description), "rviz": "true"}))
    (log,) = _of("LogInfo", missing)
    assert "rviz2 is not installed" in log.kwargs["msg"] and RVIZ in log.kwargs["msg"]
    assert "rviz2" not in {n.kwargs["executable"] for n in _of("Node", missing)}
    monkeypatch.setattr(ament_index_python.packages, "get_package_share_directory",
                        lambda package: str(tmp_path) if package == "rviz2" else _not_installed(package))
    installed = opaque.kwargs["function"](Context({**_defaults(description), "rviz": "true", "namespace": "robot1"}))
    (rviz,) = [n for n in _of("Node", installed) if n.kwargs["executable"] == "rviz2"]
    assert rviz.kwargs["arguments"] == ["-d", RVIZ] and rviz.kwargs["namespace"] == "/robot1"
    assert not _of("LogInfo", installed)
    off = opaque.kwargs["function"](Context(_defaults(description)))
    assert not _of("LogInfo", off) and "rviz2" not in {n.kwargs["executable"] for n in _of("Node", off)}
    (declared,) = [a for a in _of("DeclareLaunchArgument", description) if a.args[0] == "rviz_config"]
    assert declared.kwargs["default_value"].args[0][1:] == ["config", "robotino.rviz"]


def test_robots_starts_the_fleets_processes_as_run_does(description):
    """``robots:=N``: the fleet executables (their nodes named by the fleet, so no name remap), each with the robots
    robot1 .. robotN and the single robot's parameters; the plant waits as `run --robots` makes it wait.
    """
    from robotino_geom_mpc.system.processes import FLEET_NODES, fleet_wait_for

    single, _ = _launch(description, lockstep="true", record="true", bag="/tmp/b")
    fleet, _ = _launch(description, lockstep="true", record="true", bag="/tmp/b", robots="3")
    assert set(fleet) == {FLEET_NODES[name] for name in LOOP} | {"recorder_node"}
    for name in LOOP:
        node = fleet[FLEET_NODES[name]]
        assert "name" not in node.kwargs and node.kwargs["namespace"] == ""
        got, want = _overrides(node), _overrides(single[name])
        assert got.pop("robots") == ["robot1", "robot2", "robot3"]
        want.pop("frame_prefix", None)  # each robot's own, set by the fleet
        if name == "plant_node":
            assert got.pop("lockstep_wait_for") == fleet_wait_for(3, True)
            want.pop("lockstep_wait_for")
        assert got == want, name
    # realtime: a preview every 10 periods, the controllers' reference timeout over them (as run --robots)
    fleet, _ = _launch(description, lockstep="false", robots="3")
    assert _overrides(fleet["fleet_trajectory_node"])["preview_every"] == 10
    assert _overrides(fleet["fleet_controller_node"])["reference_timeout_s"] == pytest.approx(0.2, abs=1e-12)
