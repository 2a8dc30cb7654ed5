"""Sphinx extension: the pages generated from the code (one source), written before the build reads them.

* ``_generated/parameters.md``: every node's parameters from their `ParamSpec` tuples (name, type, unit, range,
  description, default), as generate_parameter_library does for ros2_controllers;
* ``_generated/scenarios.md``: the scenario registry (`scenarios.SCENARIOS`);
* ``_generated/launch_arguments.md``: the launch file's `DeclareLaunchArgument` calls (read with `ast`);
* ``_generated/api.md``: one autodoc section per module of the two packages.
"""

from __future__ import annotations

import ast
import math
import re
import pkgutil
from pathlib import Path
from typing import Any

OUT = "_generated"


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _range(spec) -> str:
    if spec.choices:
        return ", ".join(f"`{c}`" for c in spec.choices)
    if spec.min is None and spec.max is None:
        return ""
    low = "" if spec.min is None else f"{spec.min:g} {'<' if spec.min_exclusive else '<='} "
    high = "" if spec.max is None or (isinstance(spec.max, float) and math.isinf(spec.max)) else f" <= {spec.max:g}"
    return f"{low}value{high}"


def _table(specs, defaults: dict[str, Any]) -> list[str]:
    rows = ["| parameter | type | unit | range | default | description |", "| --- | --- | --- | --- | --- | --- |"]
    for spec in specs:
        default = defaults.get(spec.name, "")
        rows.append(f"| `{spec.name}` | {spec.type.__name__} | {_cell(spec.unit)} | {_cell(_range(spec))} | "
                    f"{_cell(repr(default) if isinstance(default, str) else default)} | {_cell(spec.description)} |")
    return rows


def parameters_page() -> str:
    from robotino_geom_mpc.nodes import controller_inputs, follow_path_server, goal_inputs, goal_sender, \
        robot_description_node
    from robotino_geom_mpc.nodes import trajectory_node
    from robotino_geom_mpc.params.specs import CONTROL_SPECS, ROBOT_SPECS
    from robotino_geom_mpc.ros.parameters import spec_defaults
    from robotino_sim_node import plant_node

    shared = spec_defaults()
    lines = [
        "# Parameter reference",
        "",
        "Generated from the parameter specs (`robotino_geom_mpc.params.specs` and each node's `*_SPECS`): the",
        "nodes declare exactly these, with the description and range, and validate every value at start and on",
        "every set. Defaults of the shared section are the default preset's (`config/robotino3.yaml`).",
        "",
        "## Shared by every node: the robot (`/**` section of a parameter file)",
        "",
        *_table(ROBOT_SPECS, shared),
        "",
        "## Shared by every node: the controller's settings",
        "",
        *_table(CONTROL_SPECS, shared),
        "",
        "## plant_node (`robotino_plant`)",
        "",
        *_table(plant_node.PLANT_SPECS, getattr(plant_node, "_PLANT_DEFAULTS", {})),
        "",
        "## controller_node (`robotino_controller`)",
        "",
        *_table(controller_inputs.CONTROLLER_SPECS, controller_inputs.CONTROLLER_DEFAULTS),
        "",
        "## trajectory_node (`robotino_trajectory`)",
        "",
        *_table(trajectory_node.TRAJECTORY_SPECS + goal_inputs.GOAL_SPECS + follow_path_server.FOLLOW_PATH_SPECS,
                {**getattr(trajectory_node, "_DEFAULTS", {}), **goal_inputs.GOAL_DEFAULTS,
                 **follow_path_server.FOLLOW_PATH_DEFAULTS}),
        "",
        "## robot_description_publisher",
        "",
        *_table(robot_description_node.DESCRIPTION_SPECS, {}),
        "",
        "## goal_sender",
        "",
        *_table(goal_sender.SENDER_SPECS, {}),
        "",
        "The recorder node's parameters (`output`, `topics`, `qos_depth`, `flush_period_s`, `compression`, ...)",
        "are declared in `recording/recorder_node.py` with their descriptions (`ros2 param describe`).",
        "",
    ]
    return "\n".join(lines)


def scenarios_page() -> str:
    from robotino_geom_mpc.scenarios import SCENARIOS

    lines = ["# Scenarios", "",
             "Generated from the registry (`robotino_geom_mpc/scenarios.py`); every verb, node and the launch file",
             "take these names (`--scenario`, `scenario:=`). How to add one: {doc}`../howto/adding_a_scenario`.", "",
             "| scenario | reference | duration [s] | controller's model | odometry noise | description |",
             "| --- | --- | --- | --- | --- | --- |"]
    for name, s in SCENARIOS.items():
        model = ("the true robot" if s.mismatch is None else
                 f"mass x{s.mismatch.mass:g}, inertia x{s.mismatch.inertia:g}, friction x{s.mismatch.friction:g}")
        noise = ("none" if s.noise.position_m == s.noise.yaw_rad == 0.0 else
                 f"{s.noise.position_m:g} m, {s.noise.yaw_rad:g} rad")
        duration = "until stopped" if s.reference == "goals" else f"{s.duration_s:.1f}"
        lines.append(f"| `{name}` | `{s.reference}` | {duration} | {model} | {noise} | {_cell(s.description)} |")
    return "\n".join(lines) + "\n"


def launch_arguments_page(launch_file: Path) -> str:
    lines = ["| argument | default | description |", "| --- | --- | --- |"]
    for node in ast.walk(ast.parse(launch_file.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "DeclareLaunchArgument":
            name = node.args[0].value
            keywords = {k.arg: k.value for k in node.keywords}
            default = keywords.get("default_value")
            shown = (repr(default.value) if isinstance(default, ast.Constant)
                     else f"`{ast.unparse(default)}`" if default is not None else "")
            description = keywords.get("description")
            text = " ".join(ast.literal_eval(description).split()) if description is not None else ""
            lines.append(f"| `{name}` | {_cell(shown)} | {_cell(text)} |")
    return "\n".join(lines) + "\n"


def api_page() -> str:
    import robotino_geom_mpc
    import robotino_sim_node

    lines = ["# API", "", "The modules' numpydoc docstrings (autodoc). The math core first, in the paper's order.", ""]
    order = ("errors", "arrays", "params", "model", "geometric", "control", "reference", "scenarios", "offline",
             "description", "system", "ros", "nodes", "recording", "cli", "bench")
    names = []
    for package in (robotino_geom_mpc, robotino_sim_node):
        names += [m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + ".")
                  if not m.ispkg and not m.name.endswith("__main__")]

    def key(name: str) -> tuple[int, str]:
        parts = name.split(".")
        top = parts[1] if parts[0] == "robotino_geom_mpc" else "~sim"
        return (order.index(top) if top in order else len(order), name)

    for name in sorted(names, key=key):
        lines += [f"## `{name}`", "", "```{eval-rst}", f".. automodule:: {name}", "```", ""]
    return "\n".join(lines)


_LITERAL = re.compile(r"(``.*?``)")


def _escape(line: str) -> str:
    """`line` with the plain-text math of the docstrings (|x|, x'', a * b) kept from reStructuredText markup."""
    bullet = re.match(r"\s*\* ", line)  # a list item keeps its marker
    start = bullet.end() if bullet else 0
    parts = _LITERAL.split(line[start:])
    return line[:start] + "".join(part if part.startswith("``") else part.replace("\\", "\\\\").replace("|", "\\|")
                                  .replace("*", "\\*").replace("_ ", "\\_ ") for part in parts)


def plain_docstrings(app, what, name, obj, options, lines) -> None:
    """The docstrings are numpydoc with plain-text math: modules' as written (a literal block after their first
    paragraph, which keeps their aligned tables), the others with the math escaped.
    """
    if what == "module":
        head = []
        while lines and lines[0].strip():
            head.append(lines.pop(0))
        body = [f"    {line}" if line.strip() else "" for line in lines]
        lines[:] = [_escape(line) for line in head] + ([""] + ["::", ""] + body if any(body) else [])
    else:
        lines[:] = [_escape(line) for line in lines]


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:  # unchanged pages keep their time (no rebuild)
        path.write_text(text)


def generate(app) -> None:
    src = Path(app.srcdir)
    out = src / OUT
    _write(out / "parameters.md", parameters_page())
    _write(out / "scenarios.md", scenarios_page())
    _write(out / "launch_arguments.md", launch_arguments_page(src.parent / "launch" / "robotino_geom_mpc.launch.py"))
    _write(out / "api.md", api_page())


def setup(app) -> dict[str, Any]:
    app.connect("builder-inited", generate)
    app.connect("autodoc-process-docstring", plain_docstrings, priority=400)  # before napoleon (500)
    return {"version": "1", "parallel_read_safe": True}
