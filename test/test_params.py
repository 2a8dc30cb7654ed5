"""Parameter files: presets load, every kind of bad file gives a one-line ParamError naming key and file."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from robotino_geom_mpc.params.specs import ParamError, ROBOT_SPECS, CONTROL_SPECS
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import preset_file

REPO = Path(__file__).resolve().parents[1]


def _preset_tree(name="robotino3"):
    return yaml.safe_load(preset_file(name).read_text())


def _write(tmp_path, tree_or_text, name="bad.yaml"):
    path = tmp_path / name
    path.write_text(tree_or_text if isinstance(tree_or_text, str) else yaml.safe_dump(tree_or_text))
    return path


@pytest.mark.unit
@pytest.mark.parametrize("name", ["robotino3", "robotino2"])
def test_presets_load_and_match_the_yaml(name):
    robot, control = load_params(preset_file(name))
    raw = _preset_tree(name)["/**"]["ros__parameters"]
    assert robot.mass_kg == raw["robot"]["mass_kg"]
    assert robot.inductance_h == raw["motor"]["inductance_h"]
    assert control.horizon == raw["control"]["horizon"]
    # effective mass and inertia: body plus three rotors reflected through the gear (independent formula)
    rob = raw["robot"]
    m_rotor = raw["motor"]["rotor_inertia_kg_m2"] * rob["gear_ratio"] ** 2 / rob["wheel_radius_m"] ** 2
    assert robot.M == pytest.approx(raw["robot"]["mass_kg"] + 1.5 * m_rotor)
    assert robot.J == pytest.approx(rob["yaw_inertia_kg_m2"] + 3 * rob["wheel_distance_m"] ** 2 * m_rotor)


@pytest.mark.unit
def test_every_spec_is_in_the_presets():
    flat = _preset_tree()["/**"]["ros__parameters"]
    for spec in ROBOT_SPECS + CONTROL_SPECS:
        section, key = spec.name.split(".")
        assert key in flat[section], spec.name


@pytest.mark.unit
def test_default_is_robotino3():
    assert load_params()[0] == load_params(preset_file("robotino3"))[0]


def _mutate(section, key, value):
    tree = _preset_tree()
    if value is _DELETE:
        del tree["/**"]["ros__parameters"][section][key]
    else:
        tree["/**"]["ros__parameters"][section][key] = value
    return tree


_DELETE = object()


@pytest.mark.unit
@pytest.mark.parametrize(
    "section, key, value, expect",
    [
        ("robot", "mass_kg", _DELETE, "missing"),
        ("robot", "mass_kg", "heavy", "must be a number"),
        ("robot", "mass_kg", True, "must be a number"),
        ("robot", "mass_kg", 0.0, "must be >"),
        ("robot", "mass_kg", -3.0, "must be >"),
        ("motor", "inductance_h", float("nan"), "finite"),
        ("control", "horizon", 4.5, "must be an integer"),
        ("control", "mode", "fast", "must be one of"),
    ],
)
def test_bad_values_name_the_key_and_the_file(tmp_path, section, key, value, expect):
    path = _write(tmp_path, _mutate(section, key, value))
    with pytest.raises(ParamError) as info:
        load_params(path)
    message = str(info.value)
    assert f"{section}.{key}" in message and str(path) in message and expect in message
    assert "\n" not in message


@pytest.mark.unit
@pytest.mark.parametrize(
    "text, expect",
    [
        ("robot: [unclosed\n", "not valid YAML"),
        ("- just\n- a list\n", "Sequences cannot be key at line 1"),  # rcl's words (params.rcl_yaml)
        ("/**:\n  ros__parameters: 5\n", "Cannot have a value before ros__parameters at line 2"),
        ("/**: [1, 2]\n", "Sequences can only be values and not keys in params. Error at line 1"),
        ("/**:\n  ros__parameters:\n    a: &x 1\n    b: *x\n", "Will not support aliasing at line 4"),
        ("other_node:\n  ros__parameters: {robot: {mass_kg: 1.0}}\n", "no '/**' section"),
    ],
)
def test_bad_files_name_the_file(tmp_path, text, expect):
    path = _write(tmp_path, text)
    with pytest.raises(ParamError) as info:
        load_params(path)
    assert str(path) in str(info.value) and expect in str(info.value)


@pytest.mark.unit
def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(ParamError, match="nope.yaml"):
        load_params(path)


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "robotino_geom_mpc", *args], cwd=REPO, capture_output=True, text=True, timeout=120
    )


@pytest.mark.ros
@pytest.mark.parametrize(
    "content, key",
    [
        (None, "nope.yaml"),
        ("mass", "robot.mass_kg"),
    ],
)
def test_cli_reports_bad_parameter_files_in_one_line_with_status_2(tmp_path, content, key):
    path = tmp_path / "nope.yaml" if content is None else _write(tmp_path, _mutate("robot", "mass_kg", -1.0))
    result = _cli("analyze", "--params", str(path))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr and key in lines[0] and str(path.name) in lines[0]
    assert result.stdout == ""


# --- SpecParameters(check=...): the whole candidate set is checked on start and on every set -----------------


def _ratio_check(values):
    """Refuses a q_x / r_x ratio below 1e6 (a stand-in for the controller's stability check)."""
    ratio = values["control.q_x"] / values["control.r_x"]
    return None if ratio >= 1e6 else f"q_x / r_x = {ratio:g} < 1e6"


@pytest.fixture
def stand_in():
    """Makes nodes in their own context declaring the robot/control parameters (with `_ratio_check` by default)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node

    from robotino_geom_mpc.params.specs import ALL_SPECS
    from robotino_geom_mpc.ros.parameters import SpecParameters, spec_defaults

    context = Context()
    rclpy.init(context=context)
    nodes = []
    seen = []

    def make(check=_ratio_check, **overrides):
        from rclpy.parameter import Parameter

        node = Node("check_stand_in", context=context,
                    parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
        nodes.append(node)
        params = SpecParameters(node, ALL_SPECS, spec_defaults(), seen.append, check=check)
        return node, params

    yield make, seen
    for node in nodes:
        node.destroy_node()
    rclpy.shutdown(context=context)


@pytest.mark.ros
def test_check_refuses_a_set_whose_complete_values_fail_and_keeps_the_old_ones(stand_in):
    from rclpy.parameter import Parameter

    make, seen = stand_in
    node, params = make()
    q, r = params["control.q_x"], params["control.r_x"]
    assert q / r >= 1e6  # the preset passes
    # r_x alone is in range, but together with the current q_x the ratio fails
    result = node.set_parameters([Parameter("control.r_x", value=q / 1e5)])[0]
    assert not result.successful and "q_x / r_x = 100000" in result.reason
    assert (params["control.q_x"], params["control.r_x"]) == (q, r) and seen == []
    assert node.get_parameter("control.r_x").value == r
    # both at once: the candidate is the current values updated by the whole set
    result = node.set_parameters_atomically([Parameter("control.q_x", value=1e7), Parameter("control.r_x", value=1.0)])
    assert result.successful
    assert (params["control.q_x"], params["control.r_x"]) == (1e7, 1.0) and seen == [{"control.q_x": 1e7,
                                                                                      "control.r_x": 1.0}]
    # a set of other parameters is checked against the current values and passes
    assert node.set_parameters([Parameter("control.horizon", value=6)])[0].successful


@pytest.mark.ros
def test_check_refuses_the_start_values_with_node_start_error(stand_in):
    from robotino_geom_mpc.ros.parameters import NodeStartError

    make, _ = stand_in
    with pytest.raises(NodeStartError, match=r"^q_x / r_x = 10 < 1e6$"):
        make(**{"control.q_x": 10.0, "control.r_x": 1.0})


@pytest.mark.ros
def test_a_check_that_raises_refuses_the_set_instead_of_crashing(stand_in):
    from rclpy.parameter import Parameter

    make, _ = stand_in
    node, params = make(check=lambda values: 1.0 / (values["control.q_y"] - 5.0) and None)  # raises at q_y = 5
    result = node.set_parameters([Parameter("control.q_y", value=5.0)])[0]
    assert not result.successful and "ZeroDivisionError" in result.reason
    assert params["control.q_y"] != 5.0


@pytest.mark.unit
def test_a_controller_without_plans_must_publish_its_plain_command():
    """``publish_plain_command`` false leaves only the plans: refused without them (the node would send nothing)."""
    from robotino_geom_mpc.nodes.controller_inputs import CONTROLLER_DEFAULTS, closed_loop_problem
    from robotino_geom_mpc.ros.parameters import spec_defaults

    values = {**spec_defaults(), **CONTROLLER_DEFAULTS}
    assert closed_loop_problem(values) is None
    assert "'publish_plain_command' false needs 'plans'" in closed_loop_problem({**values,
                                                                              "publish_plain_command": False})
    assert closed_loop_problem({**values, "publish_plain_command": False, "plans": True}) is None
