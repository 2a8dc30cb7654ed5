"""Bad ``--params-file`` files stop a node process before rclpy.init: exit 2, one stderr line naming file and key.

The nodes run as real processes (`NodeGroup`); the command line (``analyze --params``) must refuse each
single file with the same message, and a correct set of files (merged like rcl) must still start a node
with the values the files give, read back over the node's parameter services.
"""

import contextlib
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml
from harness import Harness

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.params.files import NODE_PARAMETERS, RCLPY_PARAMETERS
from robotino_geom_mpc.params.presets import preset_file
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

pytestmark = pytest.mark.ros

GOALS_EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "goals_example.yaml"
TIMEOUT_S = 120.0  # generous: the node's imports on a loaded machine; the test waits for the exit, not the time


def _preset():
    return yaml.safe_load(preset_file("robotino3").read_text())


def _without_mass():
    tree = _preset()
    del tree["/**"]["ros__parameters"]["robot"]["mass_kg"]
    return tree


def _with_plant_section():
    tree = _preset()
    tree["robotino_plant"] = {"ros__parameters": {"odometry_noise": {"position": 0.001}}}
    return tree


def _with_global_typo():
    tree = _preset()
    tree["/**"]["ros__parameters"]["control"]["horizn"] = 6
    return tree


def _with_section_typo():
    tree = _preset()
    tree["robotino_controler"] = {"ros__parameters": {"odom_timeout_s": 0.2}}
    return tree


# case -> (node executable, file content (tree or text, None: no file), words the one line must hold)
CASES = {
    "missing key": ("controller_node", _without_mass(), ["parameter 'robot.mass_kg' missing"]),
    "unknown key in a node section": (
        "plant_node", _with_plant_section(),
        ["unknown parameter 'odometry_noise.position'", "did you mean 'odometry_noise.position_m'?"],
    ),
    "unknown key in /**": ("trajectory_node", _with_global_typo(),
                           ["unknown parameter 'control.horizn'", "did you mean 'control.horizon'?"]),
    "misspelt node section": ("controller_node", _with_section_typo(),
                              ["section 'robotino_controler'", "did you mean 'robotino_controller'?"]),
    "YAML error": ("trajectory_node", "/**:\n  ros__parameters:\n    control: {q_x: [1.0\n", ["not valid YAML"]),
    "missing file": ("plant_node", None, ["cannot read parameter file"]),
}


@pytest.fixture(scope="module")
def refused(tmp_path_factory):
    """Every case started at once, each node with its file; (path, exit status, stderr lines, stdout) by case."""
    folder = tmp_path_factory.mktemp("fault_params")
    paths, started = {}, {}
    with contextlib.ExitStack() as stack:
        for i, (case, (executable, content, _)) in enumerate(CASES.items()):
            path = folder / f"case{i}.yaml"
            if content is not None:
                path.write_text(content if isinstance(content, str) else yaml.safe_dump(content))
            paths[case] = path
            group = stack.enter_context(NodeGroup(log_dir=folder / f"logs{i}"))  # one per case: logs by executable
            started[case] = group.start(executable, ros_args(path))
        for node in started.values():
            node.popen.wait(timeout=TIMEOUT_S)
    return {
        case: (paths[case], node.popen.returncode, node.stderr_path.read_text().splitlines(),
               node.stdout_path.read_text())
        for case, node in started.items()
    }


@pytest.mark.parametrize("case", list(CASES))
def test_a_bad_parameter_file_stops_the_node_with_one_line_and_status_2(refused, case):
    executable, _, words = CASES[case]
    path, status, lines, _ = refused[case]
    assert status == 2, lines
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"{executable}: error: ") and str(path) in lines[0], lines
    for word in words:
        assert word in lines[0]


def test_the_command_line_refuses_each_file_with_the_same_message(refused, capsys):
    """`analyze --params FILE` applies the same rules: the same line after the program's name, status 2 (the CLI's
    entry point in this process: its exit status and streams as a console script gives them, test_simulate_cli).
    """
    for case, (path, *_) in refused.items():
        status = main(["analyze", "--params", str(path)])
        out, err = capsys.readouterr()
        node_line = refused[case][2][0]
        assert status == 2 and out == "", case
        assert err.splitlines() == [f"robotino-geom-mpc analyze: error: {node_line.split(': error: ', 1)[1]}"]


def test_correct_files_merged_in_order_start_the_node_with_their_values(tmp_path):
    """The preset, then a file overriding one robot/control key in ``/**`` (written ``2e6``, a number for rcl),
    a controller section, and a section of another package's node: the controller starts with those values.
    """
    override = tmp_path / "override.yaml"
    override.write_text(textwrap.dedent("""\
        /**:
          ros__parameters:
            control: {q_x: 2e6}
        robotino_controller:
          ros__parameters:
            odom_timeout_s: 0.25
            use_sim_time: false
        camera_driver:
          ros__parameters: {fps: 30}
        """))
    args = ros_args(preset_file("robotino3"))
    args += ["--params-file", str(override)]
    with NodeGroup(log_dir=tmp_path / "logs") as group, Harness("fault_params_probe") as h:
        node = group.start("controller_node", args)
        values = h.get_parameters("robotino_controller", ["control.q_x", "odom_timeout_s", "robot.mass_kg"],
                                  timeout_s=TIMEOUT_S)
        assert values == [2e6, 0.25, _preset()["/**"]["ros__parameters"]["robot"]["mass_kg"]]
        assert group.stop_node(node) == 0


def test_the_registry_names_what_each_node_declares(tmp_path):
    """`NODE_PARAMETERS` against the parameters each node really declares (built in a fresh process)."""
    script = textwrap.dedent(f"""\
        import json, rclpy
        from rclpy.parameter import Parameter
        from robotino_geom_mpc.nodes.controller_node import ControllerNode
        from robotino_geom_mpc.nodes.trajectory_node import TrajectoryNode
        from robotino_geom_mpc.recording.recorder_node import RecorderNode
        from robotino_geom_mpc.nodes.goal_sender import GoalSender
        from robotino_geom_mpc.nodes.robot_description_node import RobotDescriptionNode
        from robotino_sim_node.plant_node import PlantNode
        from robotino_geom_mpc.nodes.command_buffer_node import CommandBufferNode
        from robotino_geom_mpc.nodes import fleet_controller_node, fleet_trajectory_node
        from robotino_sim_node.fleet_plant_node import FleetPlant
        rclpy.init()
        out = {{}}
        for make in (ControllerNode, TrajectoryNode, PlantNode, RobotDescriptionNode, CommandBufferNode,
                     fleet_controller_node.fleet, fleet_trajectory_node.fleet, FleetPlant,
                     lambda: RecorderNode(parameter_overrides=[Parameter("output", value={str(tmp_path / 'bag')!r})]),
                     lambda: GoalSender(parameter_overrides=[Parameter("goals_file", value={str(GOALS_EXAMPLE)!r})])):
            node = make()
            out[node.get_name()] = node.list_parameters([], 0).names
            node.destroy_node()
        rclpy.shutdown()
        print(json.dumps(out))
        """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=TIMEOUT_S)
    assert run.returncode == 0, run.stderr
    declared = json.loads(run.stdout.splitlines()[-1])
    assert set(declared) == set(NODE_PARAMETERS)
    for name, names in declared.items():
        assert sorted(n for n in names if n not in RCLPY_PARAMETERS) == sorted(NODE_PARAMETERS[name]), name
