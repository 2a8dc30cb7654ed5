"""The launch file's description, built with stand-ins for `launch` and `launch_ros` (neither is on PyPI).

The stand-ins record what the file passes to each action, so the test checks the file's own logic:
which nodes start under which condition, with which parameters, and that every launch configuration
it reads is a declared argument. (That it compiles and names installed files: test_colcon_build.)
"""

import importlib.util
import sys
import types
from pathlib import Path

import pytest

from robotino_geom_mpc.ros.processes import RECORDER_WAIT_FOR

LAUNCH_FILE = Path(__file__).resolve().parents[1] / "launch" / "robotino_geom_mpc.launch.py"


class Recorded:
    """A stand-in action or substitution: keeps its arguments."""

    made: list["Recorded"] = []

    def __init__(self, *args, **kwargs) -> None:
        self.args, self.kwargs = args, kwargs
        Recorded.made.append(self)


def _kind(name: str) -> type:
    return type(name, (Recorded,), {})


STAND_INS = {
    "launch": {"LaunchDescription": _kind("LaunchDescription")},
    "launch.actions": {"DeclareLaunchArgument": _kind("DeclareLaunchArgument")},
    "launch.conditions": {"IfCondition": _kind("IfCondition"), "UnlessCondition": _kind("UnlessCondition")},
    "launch.substitutions": {n: _kind(n) for n in ("LaunchConfiguration", "PathJoinSubstitution", "PythonExpression")},
    "launch_ros": {},
    "launch_ros.actions": {"Node": _kind("Node")},
    "launch_ros.parameter_descriptions": {"ParameterValue": _kind("ParameterValue")},
    "launch_ros.substitutions": {"FindPackageShare": _kind("FindPackageShare")},
}


@pytest.fixture
def description(monkeypatch):
    for name, attrs in STAND_INS.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    Recorded.made = []
    spec = importlib.util.spec_from_file_location("robotino_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description().args[0]


def _of(kind: str, items) -> list[Recorded]:
    return [a for a in items if type(a).__name__ == kind]


def _config_name(condition: Recorded) -> str:
    (config,) = condition.args
    assert type(config).__name__ == "LaunchConfiguration"
    return config.args[0]


def test_every_launch_configuration_read_is_a_declared_argument(description):
    declared = {a.args[0] for a in _of("DeclareLaunchArgument", description)}
    read = {c.args[0] for c in _of("LaunchConfiguration", Recorded.made)}
    assert read <= declared and {"scenario", "lockstep", "record", "bag"} <= declared


def test_with_record_the_recorder_starts_and_the_plant_waits_for_its_subscriptions(description):
    nodes = _of("Node", description)
    plants = [n for n in nodes if n.kwargs["executable"] == "plant_node"]
    by_condition = {(type(p.kwargs["condition"]).__name__, _config_name(p.kwargs["condition"])): p for p in plants}
    assert set(by_condition) == {("IfCondition", "record"), ("UnlessCondition", "record")}  # one plant either way
    waiting = by_condition[("IfCondition", "record")].kwargs["parameters"][1]
    plain = by_condition[("UnlessCondition", "record")].kwargs["parameters"][1]
    assert waiting["lockstep_wait_for"] == list(RECORDER_WAIT_FOR)
    assert "lockstep_wait_for" not in plain  # the plant's default: the controller and the trajectory
    assert {k: v for k, v in waiting.items() if k != "lockstep_wait_for"}.keys() == plain.keys()
    (recorder,) = [n for n in nodes if n.kwargs["executable"] == "recorder_node"]
    assert type(recorder.kwargs["condition"]).__name__ == "IfCondition"
    assert _config_name(recorder.kwargs["condition"]) == "record"
    others = [n for n in nodes if n.kwargs["executable"] in ("trajectory_node", "controller_node")]
    assert len(others) == 2 and all("condition" not in n.kwargs for n in others)
