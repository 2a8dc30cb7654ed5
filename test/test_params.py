"""Parameter files: presets load, every kind of bad file gives a one-line ParamError naming key and file."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from robotino_geom_mpc.core.params import ParamError, ROBOT_SPECS, CONTROL_SPECS, load_params, preset_file

REPO = Path(__file__).resolve().parents[1]


def _preset_tree(name="robotino3"):
    return yaml.safe_load(preset_file(name).read_text())


def _write(tmp_path, tree_or_text, name="bad.yaml"):
    path = tmp_path / name
    path.write_text(tree_or_text if isinstance(tree_or_text, str) else yaml.safe_dump(tree_or_text))
    return path


@pytest.mark.parametrize("name", ["robotino3", "robotino2"])
def test_presets_load_and_match_the_yaml(name):
    robot, control = load_params(preset_file(name))
    raw = _preset_tree(name)["/**"]["ros__parameters"]
    assert robot.mass_kg == raw["robot"]["mass_kg"]
    assert robot.inductance_h == raw["motor"]["inductance_h"]
    assert control.horizon == raw["control"]["horizon"]
    # effective mass and inertia: body plus three rotors reflected through the gear (independent formula)
    m_rotor = raw["motor"]["rotor_inertia_kg_m2"] * raw["robot"]["gear_ratio"] ** 2 / raw["robot"]["wheel_radius_m"] ** 2
    assert robot.M == pytest.approx(raw["robot"]["mass_kg"] + 1.5 * m_rotor)
    assert robot.J == pytest.approx(raw["robot"]["yaw_inertia_kg_m2"] + 3 * raw["robot"]["wheel_distance_m"] ** 2 * m_rotor)


def test_every_spec_is_in_the_presets():
    flat = _preset_tree()["/**"]["ros__parameters"]
    for spec in ROBOT_SPECS + CONTROL_SPECS:
        section, key = spec.name.split(".")
        assert key in flat[section], spec.name


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


@pytest.mark.parametrize(
    "text, expect",
    [
        ("robot: [unclosed\n", "not valid YAML"),
        ("- just\n- a list\n", "expected a mapping"),
        ("/**:\n  ros__parameters: 5\n", "'/**' must contain a 'ros__parameters' mapping"),
        ("/**: [1, 2]\n", "'/**' must contain a 'ros__parameters' mapping"),
        ("other_node:\n  ros__parameters: {robot: {mass_kg: 1.0}}\n", "no '/**' section"),
    ],
)
def test_bad_files_name_the_file(tmp_path, text, expect):
    path = _write(tmp_path, text)
    with pytest.raises(ParamError) as info:
        load_params(path)
    assert str(path) in str(info.value) and expect in str(info.value)


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(ParamError, match="nope.yaml"):
        load_params(path)


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "robotino_geom_mpc", *args], cwd=REPO, capture_output=True, text=True, timeout=120
    )


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
