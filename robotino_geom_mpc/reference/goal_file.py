"""Goal files of ``robotino-geom-mpc run --scenario goals --goals FILE``: timed goals and planner paths.

A YAML (or JSON) file with a list ``items``; each item has ``t`` (seconds after the run's start: the
robot's first odometry) and either ``goal: [x, y, yaw]`` (one pose, [m], [m], [rad]) or ``path:
[[x, y, yaw], ...]`` (one or more poses), and optionally ``frame`` (the header's frame_id, default
``odom``). config/goals_example.yaml is an example. `planned_end_s` plans the items offline with
`reference.goals.GoalReference` the way the trajectory node does on receipt, for the run's length.

The trajectory node's limit parameters are here too (`LIMIT_SPECS`, `LIMIT_DEFAULTS`, `motion_limits`), so
``run`` plans with the node's limits without ROS. Defaults: 0.4 m/s, 0.4 m/s^2, 2 m/s^3 per linear axis,
1.5 rad/s, 1.5 rad/s^2, 8 rad/s^3 in yaw, the rim speed of the motor's nominal speed (0 = that). They keep the
wheel currents of the closed loop below the nominal 0.86 A: 0.53 A peak on config/goals_example.yaml (``run``,
lockstep) and 0.29 A on 1.4 m diagonal moves with 3 rad turns.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robotino_geom_mpc.reference.goal_motion import GoalError, MotionLimits, nominal_rim_speed
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.params.specs import ParamSpec, params_from_values

__all__ = ["GoalItem", "LIMIT_DEFAULTS", "LIMIT_SPECS", "load_goal_file", "motion_limits", "planned_end_s"]


def _limit(name: str, what: str, unit: str) -> ParamSpec:
    return ParamSpec(f"goals.{name}", float, f"Goals scenario: largest {what} of a goal motion or path", unit,
                     0.0, 100.0, True)


LIMIT_SPECS: tuple[ParamSpec, ...] = (
    _limit("max_velocity_mps", "|x'| and |y'| (each axis of odom)", "m/s"),
    _limit("max_acceleration_mps2", "|x''| and |y''|", "m/s^2"),
    _limit("max_jerk_mps3", "|x'''| and |y'''|", "m/s^3"),
    _limit("max_angular_velocity_radps", "|theta'|", "rad/s"),
    _limit("max_angular_acceleration_radps2", "|theta''|", "rad/s^2"),
    _limit("max_angular_jerk_radps3", "|theta'''|", "rad/s^3"),
    ParamSpec("goals.max_rim_speed_mps", float, "Goals scenario: largest wheel rim speed of a motion; 0 = the "
              "motor's nominal speed at the rim (motor.nominal_speed_rpm / gear * r)", "m/s", 0.0, 100.0, False),
)
LIMIT_DEFAULTS: dict[str, float] = {
    "goals.max_velocity_mps": 0.4, "goals.max_acceleration_mps2": 0.4, "goals.max_jerk_mps3": 2.0,
    "goals.max_angular_velocity_radps": 1.5, "goals.max_angular_acceleration_radps2": 1.5,
    "goals.max_angular_jerk_radps3": 8.0, "goals.max_rim_speed_mps": 0.0,
}


def motion_limits(values: dict[str, Any]) -> MotionLimits:
    """The `MotionLimits` of flat parameter values: the robot's (`params.specs.ROBOT_SPECS`) and `LIMIT_SPECS`."""
    robot, _ = params_from_values(values, "the trajectory node's parameters")
    rim = values["goals.max_rim_speed_mps"] or nominal_rim_speed(robot)
    v, a, j, w, dw, ddw = (values[s.name] for s in LIMIT_SPECS[:6])
    return MotionLimits(v, a, j, w, dw, ddw, rim_speed_mps=rim, robot=robot)


@dataclass(frozen=True)
class GoalItem:
    """One timed item: a goal (one pose) or a path (poses), each pose (x, y, yaw)."""

    t: float
    poses: tuple[tuple[float, float, float], ...]
    is_path: bool
    frame: str = "odom"


def _poses(value: object, where: str) -> tuple[tuple[float, float, float], ...]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise GoalError(f"{where}: poses must be numbers [x, y, yaw], got {value!r}") from None
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0 or not np.isfinite(arr).all():
        raise GoalError(f"{where}: need finite poses [x, y, yaw], got {value!r}")
    return tuple((float(x), float(y), float(yaw)) for x, y, yaw in arr)


def load_goal_file(path: str | os.PathLike) -> list[GoalItem]:
    """The items of a goal file, sorted by time.

    Raises
    ------
    GoalError
        Unreadable or malformed file, naming the file and the item.
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise GoalError(f"cannot read goal file {path}: {exc}") from None
    items = data.get("items") if isinstance(data, dict) else None
    if not isinstance(items, list) or not items:
        raise GoalError(f"goal file {path}: needs a non-empty list 'items'")
    out = []
    for k, item in enumerate(items):
        where = f"goal file {path}, item {k}"
        if not isinstance(item, dict) or set(item) - {"t", "goal", "path", "frame"} or ("goal" in item) == (
                "path" in item):
            raise GoalError(f"{where}: need 't' and one of 'goal' or 'path' (and optionally 'frame'), got {item!r}")
        t = item.get("t")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0.0:
            raise GoalError(f"{where}: 't' must be a time >= 0 [s], got {t!r}")
        frame = item.get("frame", "odom")
        if not isinstance(frame, str):
            raise GoalError(f"{where}: 'frame' must be a string, got {frame!r}")
        poses = _poses([item["goal"]] if "goal" in item else item["path"], where)
        out.append(GoalItem(float(t), poses, "path" in item, frame))
    return sorted(out, key=lambda i: i.t)


def planned_end_s(items: list[GoalItem], limits: MotionLimits) -> float:
    """When the items' motions end if each is planned at its time (an estimate: items in another frame are
    skipped, yaws are taken as given where the node unwraps them to the nearest turn).
    """
    ref = GoalReference(hold_s=0.0)
    for item in items:
        if item.frame != "odom":
            continue
        if item.is_path:
            poses = np.array(item.poses)
            poses[:, 2] = np.unwrap(poses[:, 2])
            ref.follow(item.t, poses, limits)
        else:
            ref.go_to(item.t, np.array(item.poses[0]), limits)
    return ref.duration_s
