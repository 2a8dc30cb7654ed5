"""The scenario registry: durations, the name lookup, and the node overrides against the nodes' own parameters."""

import dataclasses
import math

import numpy as np
import pytest
import yaml

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.network.link import LinkParams
from robotino_geom_mpc.params.specs import ALL_SPECS
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.nodes.trajectory_node import TRAJECTORY_SPECS
from robotino_geom_mpc.scenarios import SCENARIOS, ScenarioError, get_scenario, node_parameters
from robotino_sim_node.plant_node import PLANT_SPECS

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def robot():
    return load_params()[0]


def test_default_duration_is_the_references_length():
    # the paper's circle: 2 laps of 10 s plus the 2 s of its ramps (CircleReference)
    assert SCENARIOS["paper-circle"].duration_s == SCENARIOS["robustness"].duration_s == pytest.approx(22.0)
    # no ramp-in: 2 laps plus half the ramp (the ramp-out)
    assert SCENARIOS["paper-circle-step"].duration_s == pytest.approx(21.0)


def test_paper_circle_step_starts_at_full_speed_from_rest():
    """The paper's start: the reference's velocity is 2 pi r / T at t = 0 (rest before); the ramped circle's is 0."""
    step, ramped = SCENARIOS["paper-circle-step"].make_reference(), SCENARIOS["paper-circle"].make_reference()
    assert "paper's start" in SCENARIOS["paper-circle-step"].description
    np.testing.assert_allclose(step.sample(0.0)[1], (2 * np.pi * 0.5 / 10.0, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(step.sample(-0.01)[1], 0.0, atol=0.0)
    np.testing.assert_allclose(ramped.sample(0.0)[1], 0.0, atol=1e-12)
    np.testing.assert_allclose(step.position(np.array([0.0, step.duration_s])), 0.0, atol=1e-12)
    np.testing.assert_allclose(step.sample(step.duration_s)[1], 0.0, atol=1e-12)  # at rest at the end
    # the velocity is the derivative of the position (an independent central difference)
    t, h = np.linspace(0.5, step.duration_s - 0.5, 41), 1e-6
    diff = (step.position(t + h) - step.position(t - h)) / (2 * h)
    np.testing.assert_allclose(diff, step.sample(t)[1], atol=1e-7)


def test_a_scenarios_reference_takes_options():
    ref = SCENARIOS["point-to-point"].make_reference(waypoints=[(1.0, 0.0, 0.0)])
    assert ref.position(ref.duration_s) == pytest.approx([1.0, 0.0, 0.0])
    assert SCENARIOS["robustness"].make_reference().position(5.0) == pytest.approx(
        make_reference("paper-circle").position(5.0))


@pytest.mark.parametrize("name, match", [
    ("robustnes", r"did you mean 'robustness'\?"),
    ("paper_circle", r"did you mean 'paper-circle'\?"),
    ("spiral", r"unknown scenario 'spiral' \(valid: paper-circle, paper-circle-step, lemniscate, point-to-point"),
    (None, "unknown scenario None"),
])
def test_unknown_names_are_refused_with_the_closest_one(name, match):
    with pytest.raises(ScenarioError, match=match) as info:
        get_scenario(name)
    assert isinstance(info.value, RobotinoError)
    if name == "spiral":
        assert "did you mean" not in str(info.value)


def test_controller_model_scales_mass_inertia_and_friction_only(robot):
    model = SCENARIOS["robustness"].controller_model(robot)
    changed = {f.name for f in dataclasses.fields(robot) if getattr(model, f.name) != getattr(robot, f.name)}
    assert changed == {"mass_kg", "yaw_inertia_kg_m2", "body_friction_x_n_s_per_m", "body_friction_y_n_s_per_m",
                       "body_friction_theta_n_m_s"}
    assert SCENARIOS["paper-circle"].controller_model(robot) is robot


def test_node_parameters_name_the_nodes_own_parameters_with_the_file_values_scaled(robot):
    """Keys against the config file and the nodes' specs; values against the file read with plain YAML."""
    file_values = yaml.safe_load(default_params_file().read_text())["/**"]["ros__parameters"]
    # the plant's link.* parameters (netros's branch) are the link's fields each way
    plant_names = {s.name for s in PLANT_SPECS} | {f"link.{way}.{f.name}" for way in ("up", "down")
                                                   for f in dataclasses.fields(LinkParams)}
    controller_names = {s.name for s in ALL_SPECS}
    for name in SCENARIOS:
        overrides = node_parameters(name, robot)
        assert set(overrides) == {"plant_node", "controller_node", "trajectory_node"}
        assert set(overrides["plant_node"]) <= plant_names and overrides["plant_node"]
        assert set(overrides["controller_node"]) <= controller_names
        assert overrides["trajectory_node"] == {"scenario": name}
        assert name in next(s for s in TRAJECTORY_SPECS if s.name == "scenario").choices
    robustness = node_parameters("robustness", robot)["controller_node"]
    assert set(robustness) == {"robot.mass_kg", "robot.yaw_inertia_kg_m2", "robot.body_friction_x_n_s_per_m",
                               "robot.body_friction_y_n_s_per_m", "robot.body_friction_theta_n_m_s"}
    for key, factor in (("mass_kg", 1.2), ("yaw_inertia_kg_m2", 0.8), ("body_friction_x_n_s_per_m", 2.0),
                        ("body_friction_y_n_s_per_m", 2.0), ("body_friction_theta_n_m_s", 2.0)):
        assert math.isclose(robustness[f"robot.{key}"], factor * file_values["robot"][key], rel_tol=1e-15)
    assert node_parameters("robustness", robot)["plant_node"] == {"odometry_noise.position_m": 1e-3,
                                                                  "odometry_noise.yaw_rad": 1e-3}
    assert node_parameters(SCENARIOS["lemniscate"], robot)["controller_node"] == {}
    wifi = node_parameters("wifi", robot)["plant_node"]
    assert wifi["link.up.delay_s"] == wifi["link.down.delay_s"] == 0.015 and wifi["link.down.burst_length"] == 3.0
    with pytest.raises(ScenarioError):
        node_parameters("square", robot)


def test_every_generated_scenario_table_is_the_registrys():
    """Every markdown file with the tool's markers (README.md) holds the table made from the registry."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("scenario_table", root / "tools" / "scenario_table.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    files = [p for p in [*root.glob("*.md"), *root.glob("docs/**/*.md")] if tool.BEGIN in p.read_text()]
    assert files
    for path in files:
        text = path.read_text()
        assert tool.with_table(text) == text, path
        for name, scenario in SCENARIOS.items():  # and the table names every scenario with its description
            assert f"| `{name}` | {scenario.description} |" in text, path
