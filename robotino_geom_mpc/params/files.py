"""The check of ROS 2 parameter files every entry point makes: the nodes before `rclpy.init`, the command line.

A node started with ``--ros-args --params-file FILE ...`` and ``robotino-geom-mpc VERB --params FILE``
refuse the same files with the same one-line `ParamError` naming the file and the key:

* a file that cannot be read or that rcl refuses: it is read as rcl reads it (`params.rcl_yaml`: not YAML,
  not ``name: {ros__parameters: {...}}``, an alias, a sequence of mixed types ...); what rcl accepts is
  accepted (tags such as launch_ros's ``!!python/tuple``, anchors, flow style, nested namespaces
  ``ns: {node: {ros__parameters: ...}}``, ``/**`` and ``*`` wildcards, node names with or without a
  leading slash);
* an **unknown key**: a key of a section that no node the section applies to declares (`NODE_PARAMETERS`)
  and that rclpy does not own (`RCLPY_PARAMETERS`, ``qos_overrides.*``); with "did you mean" the closest
  name. A section applies to the nodes of the package its last name names (``*`` and ``**``: all of them),
  in any namespace. A section naming none of them belongs to another package and is not checked, unless
  its name is close to one of ours (a misspelt node name);
* a key of our nodes that rcl gives no value (an empty sequence has no type: the node could not declare it);
* a **missing key**: a node that gets any robot/control parameter (`ALL_SPECS`) from the files must get
  every one of those it declares (``/**`` sections merged over the files in order, like rcl, plus its
  own sections); otherwise it would run on the preset's value for the rest without a word. Files that
  give no robot/control parameter at all (e.g. ``/**: {mode: lockstep}``) leave the preset in place;
* a robot/control or chain (``chain.*``) value of the wrong type or out of range (`validate_value`).

Values are typed as rcl types them (``1e6`` and ``nan`` are numbers, ``~`` and ``1_000`` strings, ``010`` is 8).
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.params.rcl_yaml import NO_VALUE, RclFileError, rcl_parameters
import yaml

from robotino_geom_mpc.params.specs import (
    ALL_SPECS,
    CONTROL_SPECS,
    ROBOT_SPECS,
    CHAIN_ACTIVE_SPEC,
    CHAIN_SPECS,
    LOOP_SPECS,
    RECORDED_CONTROLLER_SPECS,
    ControlParams,
    ParamError,
    RobotinoParams,
    params_from_values,
    validate_value,
)

__all__ = [
    "NODE_PARAMETERS",
    "RCLPY_PARAMETERS",
    "check_parameter_files",
    "load_params",
    "parse_parameter_file",
    "read_parameter_file",
    "write_parameter_file",
]

_ROBOT_CONTROL = tuple(s.name for s in ALL_SPECS)
_CHAIN = (CHAIN_ACTIVE_SPEC.name,) + tuple(s.name for s in CHAIN_SPECS)
_LOOP = tuple(s.name for s in LOOP_SPECS)  # the controller loop's settings
_LINK = tuple(f"link.{way}.{field}" for way in ("up", "down")
              for field in ("delay_s", "jitter_s", "loss", "burst_length", "duplicate"))  # the plant's radio link

RCLPY_PARAMETERS: tuple[str, ...] = ("use_sim_time", "start_type_description_service")
"""Parameters rclpy declares in every node (and ``qos_overrides.<topic>...`` for overridable QoS)."""

NODE_PARAMETERS: dict[str, tuple[str, ...]] = {
    "robotino_controller": _ROBOT_CONTROL + (
        "mode", *_LOOP, "frame_prefix", "command_interface", "plans", "start_enabled", "publish_predicted_path",
        "lockstep_command_readers", "publish_plain_command",
    ) + _CHAIN,
    "robotino_plant": _ROBOT_CONTROL + (
        "mode", "duration_s", "physics_rate_hz", "command_timeout_s", "lockstep_resend_s",
        "lockstep_max_realtime_factor", "lockstep_settle_s", "odometry_noise.position_m", "odometry_noise.yaw_rad",
        "seed", "timing_report", "lockstep_wait_for",
        "odometry_model", "encoder.counts_per_rev", "encoder.wheel_slip_std",
        "command_interface", "wheel_pi.kp", "wheel_pi.ki", "wheel_pi.rate_hz", "publish_tf", "frame_prefix",
        "publish_joint_states", "plans", "timing_window_s", "odom_publisher_check_s", "pairing.lease_s",
    ) + _CHAIN + _LINK,
    "robotino_trajectory": _ROBOT_CONTROL + (
        "scenario", "mode", "start_settle_s", "clock_timeout_s", "waypoints", "goals.max_velocity_mps",
        "goals.max_acceleration_mps2", "goals.max_jerk_mps3", "goals.max_angular_velocity_radps",
        "goals.max_angular_acceleration_radps2", "goals.max_angular_jerk_radps3", "goals.max_rim_speed_mps",
        "frame_prefix", "preview_points", "preview_every", "start_on_enable", "anchor_to_robot",
        "follow_path.controller_id", "follow_path.goal_checker_id", "follow_path.progress_checker_id",
        "follow_path.xy_goal_tolerance", "follow_path.yaw_goal_tolerance", "follow_path.required_movement_radius",
        "follow_path.movement_time_allowance", "follow_path.same_course_tolerance",
        "follow_path.use_path_orientations",
    ),
    "recorder": _ROBOT_CONTROL + (
        "output", "topics", "discovery_period_s", "flush_period_s", "chunk_size_bytes", "compression", "qos_depth",
        "scenario",
    ) + tuple(s.name for s in RECORDED_CONTROLLER_SPECS),
    "robot_description_publisher": _ROBOT_CONTROL + ("frame_prefix", "mode"),
    "robotino_goal_sender": ("goals_file", "mode"),
    "robotino_command_buffer": ("control.period_s", "idle_after_s", "pairing.lease_s"),
    # a fleet's own nodes (`ros.fleet`; its robots' nodes are the single ones above, in their namespaces)
    "robotino_fleet_trajectory": ("robots",),
    "robotino_fleet_controller": ("robots", "publish_predicted_path"),
    "robotino_fleet_plant": ("robots", "timing_report", "publish_tf", "publish_joint_states"),
}
"""The parameters each node of the package declares (besides rclpy's), by node name; a test compares them
with what the nodes declare."""

_SECTION_CUTOFF = 0.85  # a section name this close to one of our node names is taken as a misspelling


def _nodes_of(section: str) -> tuple[str, ...]:
    """Our nodes a section applies to (`_applies`)."""
    return tuple(n for n in NODE_PARAMETERS if _applies(section, n))


def _suggestion(word: str, candidates: Iterable[str], cutoff: float = 0.6) -> str:
    close = difflib.get_close_matches(word, list(candidates), n=1, cutoff=cutoff)
    return f"; did you mean '{close[0]}'?" if close else ""


def _known(name: str, nodes: Sequence[str]) -> bool:
    return (
        name in RCLPY_PARAMETERS
        or name.startswith("qos_overrides.")
        or any(name in NODE_PARAMETERS[n] for n in nodes)
    )


def check_parameter_files(paths: Sequence[str | os.PathLike]) -> None:
    """Check parameter files as one node list would read them (in order, later files win); see the module doc.

    Raises
    ------
    ParamError
        One line naming the file, the section where it matters, and the key.
    """
    got: dict[str, dict[str, Path]] = {n: {} for n in NODE_PARAMETERS}  # node -> robot/control key -> file
    for raw in paths:
        path = Path(raw)
        for section, values in parse_parameter_file(path).items():
            nodes = _nodes_of(section)
            if not nodes:
                last = section.rstrip("/").rsplit("/", 1)[-1]
                hint = _suggestion(last, NODE_PARAMETERS, _SECTION_CUTOFF)
                if hint:
                    raise ParamError(f"section '{section}' in {path} names no node of robotino_geom_mpc{hint}")
                continue
            for name, value in values.items():
                if not _known(name, nodes):
                    hint = _suggestion(name, {p for n in nodes for p in NODE_PARAMETERS[n]} | set(RCLPY_PARAMETERS))
                    raise ParamError(f"unknown parameter '{name}' in {path} (section '{section}'){hint}")
                if value is NO_VALUE:
                    raise ParamError(f"parameter '{name}' in {path} (section '{section}') has no value "
                                     "(rcl gives an empty list no type)")
            for spec in (CHAIN_ACTIVE_SPEC, *CHAIN_SPECS):
                if spec.name in values:
                    validate_value(spec, values[spec.name], str(path))
            for spec in ALL_SPECS:
                if spec.name in values:
                    validate_value(spec, values[spec.name], str(path))
                    for node in nodes:
                        if spec.name in NODE_PARAMETERS[node]:
                            got[node][spec.name] = path
    for node, given in got.items():
        wanted = [n for n in NODE_PARAMETERS[node] if n in _ROBOT_CONTROL]
        missing = [n for n in wanted if n not in given]
        if given and missing:
            files = ", ".join(sorted({str(p) for p in given.values()}))
            raise ParamError(
                f"parameter '{missing[0]}' missing in {files} (node '{node}' gets other robot/control parameters "
                "from it: all of them or none)"
            )


def parse_parameter_file(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """Every section of a ROS 2 parameter file as rcl reads it (`params.rcl_yaml.rcl_parameters`): node name
    (as written; namespace levels joined by '/') -> flat dotted values.

    Raises
    ------
    ParamError
        If the file cannot be read, or rcl refuses it (not YAML, not in the ``node: ros__parameters:`` form,
        an alias, a sequence of mixed types, an empty value, an invalid node name).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ParamError(f"cannot read parameter file {path}: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        return rcl_parameters(text)
    except RclFileError as exc:
        raise ParamError(f"{path}: {exc}") from None


def _applies(section: str, node: str | None) -> bool:
    """Whether a section applies to `node` (any namespace) as rclpy matches it: its last name is the node's or a
    wildcard (``/**``, ``*``); with `node` None, only the sections of every node.
    """
    last = section.rstrip("/").rsplit("/", 1)[-1]
    if node is None:
        return section.strip("/") in ("**", "*")
    return last in ("**", "*") or last == node


def read_parameter_file(path: str | os.PathLike, node: str | None = None) -> dict[str, Any]:
    """Read a ROS 2 parameter file into flat dotted names.

    The sections that apply to `node` (`_applies`: ``/**`` and the ones naming it, with or without a
    namespace) in the file's order, a later one overriding an earlier one, as rclpy merges them; with
    `node` None, the sections of every node.

    Raises
    ------
    ParamError
        As `parse_parameter_file`, or if no section applies.
    """
    values: dict[str, Any] = {}
    for section, section_values in parse_parameter_file(path).items():
        if _applies(section, node):
            values.update(section_values)
    if not values:
        raise ParamError(f"{path}: no '/**' section with 'ros__parameters' found")
    return values


def load_params(
    path: str | os.PathLike | None = None, node: str | None = None
) -> tuple[RobotinoParams, ControlParams]:
    """Load and validate the robot and control parameters of a ROS 2 parameter file.

    Parameters
    ----------
    path
        The file; None means the default preset (Robotino 3).
    node
        Optional node section whose values override `/**`.

    Raises
    ------
    ParamError
        A one-line message naming the key and the file; the file is checked
        as a node checks it (`params.files.check_parameter_files`).
    """
    path = Path(path) if path is not None else default_params_file()
    check_parameter_files([path])
    values = read_parameter_file(path, node)
    where = str(path)
    return params_from_values(values, where)


def write_parameter_file(path: str | os.PathLike, robot: RobotinoParams, control: ControlParams,
                         header: str = "") -> Path:
    """Write every robot and control parameter (`ROBOT_SPECS`, `CONTROL_SPECS`) as a ROS 2 parameter file for
    all nodes (``/**``).

    The file is what `load_params`, ``run --params`` and the nodes' ``--params-file`` read; `header` becomes
    its leading comment lines. Returns the path.
    """
    tree: dict[str, Any] = {}
    for spec in ROBOT_SPECS + CONTROL_SPECS:
        owner = robot if spec in ROBOT_SPECS else control
        node = tree
        *groups, leaf = spec.name.split(".")
        for group in groups:
            node = node.setdefault(group, {})
        value = getattr(owner, spec.attr)
        node[leaf] = value.item() if hasattr(value, "item") else value
    path = Path(path)
    comments = "".join(f"# {line}\n" for line in header.splitlines())
    path.write_text(comments + yaml.safe_dump({"/**": {"ros__parameters": tree}}, sort_keys=False), encoding="utf-8")
    return path
