"""Stand-ins for `launch` and `launch_ros` (neither is on PyPI): a launch file's description, evaluated without them.

Each stand-in action or substitution records its arguments; a launch file's `OpaqueFunction` is evaluated with a
context whose launch configurations the caller sets. test_launch_file and test_real_robot_launch read the
descriptions this way, and test/ros2_shim.py (the page test's ``ros2 launch``) starts the nodes they name.
`launch_ros_file` writes a Node's dict of parameters as launch_ros 0.26.6 does (test_launch_file pins it against
files a real launch wrote).
"""

from __future__ import annotations

import importlib.util
import os
import sys
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
LAUNCH_DIR = REPO / "launch"


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
    "launch.actions": {n: _kind(n) for n in ("DeclareLaunchArgument", "EmitEvent", "LogInfo", "OpaqueFunction",
                                             "RegisterEventHandler")},
    "launch.event_handlers": {"OnProcessExit": _kind("OnProcessExit")},
    "launch.events": {"Shutdown": _kind("Shutdown")},
    "launch.substitutions": {n: _kind(n) for n in ("EnvironmentVariable", "LaunchConfiguration",
                                                   "PathJoinSubstitution")},
    "launch_ros": {},
    "launch_ros.actions": {"Node": _kind("Node")},
    "launch_ros.substitutions": {"FindPackageShare": _kind("FindPackageShare")},
}


class Configurations(dict):
    """`LaunchContext.launch_configurations` (name -> string), remembering which names were read."""

    def __init__(self, values: dict[str, str]) -> None:
        super().__init__(values)
        self.read: set[str] = set()

    def __getitem__(self, name: str) -> str:
        self.read.add(name)
        return super().__getitem__(name)


class Context:
    """The `LaunchContext` an `OpaqueFunction` gets, reduced to what the files may use."""

    def __init__(self, values: dict[str, str]) -> None:
        self.launch_configurations = Configurations(values)


def install(setitem: Callable[[dict, str, Any], None] | None = None) -> None:
    """Put the stand-in modules in `sys.modules` (through `setitem`, e.g. ``monkeypatch.setitem``, if given)."""
    for name, attrs in STAND_INS.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        if setitem is None:
            sys.modules[name] = module
        else:
            setitem(sys.modules, name, module)


def load_description(launch_file: Path) -> tuple:
    """The actions of `launch_file`'s description (the stand-ins installed first)."""
    Recorded.made = []
    spec = importlib.util.spec_from_file_location(f"launch_{launch_file.name.split('.')[0]}", launch_file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description().args[0]


def of(kind: str, items) -> list[Recorded]:
    """The items of stand-in type `kind`."""
    return [a for a in items if type(a).__name__ == kind]


def perform(value: Any, configurations: dict[str, str], share: Callable[[str], str]) -> str:
    """A substitution as launch performs it: text, LaunchConfiguration, EnvironmentVariable, a PathJoinSubstitution
    of these and FindPackageShare (`share`: package -> its share directory).
    """
    if isinstance(value, str):
        return value
    kind = type(value).__name__
    if kind == "LaunchConfiguration":
        return configurations[value.args[0]]
    if kind == "EnvironmentVariable":
        name = value.args[0]
        return os.environ[name] if name in os.environ else perform(value.kwargs["default_value"], configurations,
                                                                    share)
    if kind == "FindPackageShare":
        return share(value.args[0])
    if kind == "PathJoinSubstitution":
        return os.path.join(*(perform(v, configurations, share) for v in value.args[0]))
    raise TypeError(f"no stand-in performs {kind}")


def evaluate(description, arguments: dict[str, str], share: Callable[[str], str]) -> tuple[list, Context]:
    """The actions the description's OpaqueFunction returns for `arguments` over the declared defaults."""
    values: dict[str, str] = {}
    for declared in of("DeclareLaunchArgument", description):
        values[declared.args[0]] = perform(declared.kwargs["default_value"], values, share)
    context = Context({**values, **arguments})
    (opaque,) = of("OpaqueFunction", description)
    return opaque.kwargs["function"](context), context


def _launch_ros_value(value):
    """A value as launch_ros 0.26.6 evaluates it (normalize_parameters.py, evaluate_parameters.py): a string goes
    through a YAML round trip, a list becomes a tuple of one type (ints and floats: floats).
    """
    if isinstance(value, str):
        return yaml.safe_load(yaml.dump(value))
    if isinstance(value, (list, tuple)):
        kinds = {type(v) for v in value}
        if kinds <= {int, float} and float in kinds:
            return tuple(float(v) for v in value)
        return tuple(yaml.safe_load(yaml.dump(v)) if isinstance(v, str) else v for v in value)
    return value


def launch_ros_file(node: Recorded, params: dict) -> str:
    """The text launch_ros 0.26.6 writes for a dict of a Node's ``parameters`` (`Node._create_params_file_from_dict`):
    nested dicts flattened with '.', under the node's full name (``/<namespace>/<name>``), '/**' for a node
    without a name, with ``yaml.dump(..., default_flow_style=False)``.
    """
    flat = {}

    def walk(tree: dict, prefix: str = "") -> None:
        for key, value in tree.items():
            if isinstance(value, dict):
                walk(value, f"{prefix}{key}.")
            else:
                flat[f"{prefix}{key}"] = _launch_ros_value(value)

    walk(params)
    name = node.kwargs.get("name")
    key = "/**" if name is None else f"{node.kwargs['namespace'].rstrip('/')}/{name}"
    return yaml.dump({key: {"ros__parameters": flat}}, default_flow_style=False)
