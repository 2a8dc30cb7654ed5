"""Parameters of the Robotino and of its controller: one spec, loaded from ROS 2 parameter files.

The spec (`ROBOT_SPECS`, `CONTROL_SPECS`) is the single source of truth for
names, types, ranges and descriptions: the loader validates a YAML file
against it and the ROS nodes declare their parameters from it.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import yaml

from robotino_geom_mpc.core.errors import RobotinoError
from robotino_geom_mpc.core.estimator import TWIST_MODELS

__all__ = [
    "ParamSpec",
    "ParamError",
    "ROBOT_SPECS",
    "CONTROL_SPECS",
    "ALL_SPECS",
    "RobotinoParams",
    "ControlParams",
    "config_file",
    "default_params_file",
    "preset_file",
    "parse_parameter_file",
    "read_parameter_file",
    "load_params",
    "params_from_values",
    "validate_value",
]


class ParamError(RobotinoError, ValueError):
    """A parameter file or value that is missing, mistyped or out of range."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: dotted ROS name, type, unit, allowed range and description.

    Bounds are inclusive unless `min_exclusive` is set; `choices` restricts a
    string parameter.
    """

    name: str
    type: type
    description: str
    unit: str = ""
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = True
    choices: tuple[str, ...] = ()

    @property
    def attr(self) -> str:
        """Field name in the dataclass (the last component of the dotted name)."""
        return self.name.rsplit(".", 1)[-1]


def _pos(name: str, description: str, unit: str, max_value: float | None = None) -> ParamSpec:
    return ParamSpec(name, float, description, unit, min=0.0, max=max_value, min_exclusive=True)


ROBOT_SPECS: tuple[ParamSpec, ...] = (
    _pos("robot.mass_kg", "Body mass M (eq. 3, 9)", "kg", 1000.0),
    _pos("robot.yaw_inertia_kg_m2", "Body yaw inertia J (eq. 3, 9)", "kg m^2", 100.0),
    _pos("robot.wheel_radius_m", "Omni-wheel radius r", "m", 1.0),
    _pos("robot.wheel_distance_m", "Distance l from the centre to each wheel (eq. 9)", "m", 5.0),
    _pos("robot.gear_ratio", "Motor-to-wheel gear ratio (erratum 4)", "", 1000.0),
    ParamSpec("robot.body_friction_x_n_s_per_m", float, "Body viscous friction k_x (eq. 3)", "N s/m", 0.0, 1e4, False),
    ParamSpec("robot.body_friction_y_n_s_per_m", float, "Body viscous friction k_y (eq. 3)", "N s/m", 0.0, 1e4, False),
    ParamSpec("robot.body_friction_theta_n_m_s", float, "Body viscous friction k_theta (eq. 3)", "N m s", 0.0, 1e4, False),
    _pos("motor.resistance_ohm", "Armature resistance R (eq. 10)", "ohm", 1e3),
    _pos("motor.inductance_h", "Armature inductance L (eq. 10)", "H", 10.0),
    _pos("motor.torque_constant_n_m_per_a", "Torque and back-EMF constant Km (eq. 10)", "N m/A", 10.0),
    ParamSpec("motor.rotor_inertia_kg_m2", float, "Rotor inertia (reflected into M and J)", "kg m^2", 0.0, 1.0, False),
    ParamSpec("motor.viscous_friction_n_m_s", float, "Motor viscous friction K (eq. 10)", "N m s/rad", 0.0, 1.0, False),
    _pos("motor.nominal_current_a", "Nominal (continuous) motor current", "A", 100.0),
    _pos("motor.supply_voltage_v", "Supply voltage, the limit on |U|", "V", 1000.0),
    _pos("motor.nominal_speed_rpm", "Nominal motor speed", "rpm", 1e6),
)

CONTROL_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("control.period_s", float, "Control period Ts", "s", 0.0, 1.0, True),
    ParamSpec("control.horizon", int, "MPC prediction horizon N (eqs. 50-53)", "", 1, 200, False),
    ParamSpec("control.q_x", float, "Output weight Q_p of the x MPC (eq. 54)", "1/m^2", 0.0, 1e15, True),
    ParamSpec("control.q_y", float, "Output weight Q_p of the y MPC (eq. 54)", "1/m^2", 0.0, 1e15, True),
    ParamSpec("control.q_theta", float, "Output weight Q_p of the theta MPC (eq. 54)", "1/rad^2", 0.0, 1e15, True),
    ParamSpec("control.r_x", float, "Input-increment weight R_p of the x MPC (eq. 54)", "s^4/m^2", 0.0, 1e15, True),
    ParamSpec("control.r_y", float, "Input-increment weight R_p of the y MPC (eq. 54)", "s^4/m^2", 0.0, 1e15, True),
    ParamSpec("control.r_theta", float, "Input-increment weight R_p of the theta MPC (eq. 54)", "s^4/rad^2", 0.0, 1e15, True),
    ParamSpec(
        "control.mode",
        str,
        "closed_form: unconstrained MPC (eq. 56); constrained: QP with wheel current and voltage limits",
        choices=("closed_form", "constrained"),
    ),
    ParamSpec(
        "control.odometry_filter_time_constant_s",
        float,
        "Time constant tau of the odometry pose filter (core.estimator): the position the MPCs see follows the "
        "measured pose through a first-order lag tau, carried by the measured velocity; 0 = raw pose (the paper)",
        "s",
        0.0,
        60.0,
        False,
    ),
    ParamSpec(
        "control.odometry_twist",
        str,
        "How the odometry's twist is measured, hence the pose filter's predictor (core.estimator): "
        "instantaneous (velocity at the stamp: trapezoid) or period_mean (mean since the previous message, "
        "as wheel-encoder odometry: the pose advance that built the measured pose)",
        choices=TWIST_MODELS,
    ),
    ParamSpec(
        "control.current_limit_a",
        float,
        "Wheel current limit of the closed-form mode (core.drive.InverseDrive.limited_step): when a wheel's "
        "period-average or end current would exceed it, or a voltage the supply, the commanded accelerations u are "
        "scaled by one factor (direction kept); 0 = no limit, voltages clipped per wheel (the paper)",
        "A",
        0.0,
        100.0,
        False,
    ),
)

ALL_SPECS: tuple[ParamSpec, ...] = ROBOT_SPECS + CONTROL_SPECS


def validate_value(spec: ParamSpec, value: Any, where: str = "") -> Any:
    """Check one value against its spec; return it converted (int -> float where a float is wanted).

    Raises
    ------
    ParamError
        Naming the parameter (and `where`, e.g. the file) when the type or range is wrong.
    """
    at = f" in {where}" if where else ""
    if spec.type is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParamError(f"parameter '{spec.name}'{at} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ParamError(f"parameter '{spec.name}'{at} must be finite, got {value!r}")
    elif spec.type is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParamError(f"parameter '{spec.name}'{at} must be an integer, got {value!r}")
    elif spec.type is str:
        if not isinstance(value, str):
            raise ParamError(f"parameter '{spec.name}'{at} must be a string, got {value!r}")
        if spec.choices and value not in spec.choices:
            raise ParamError(f"parameter '{spec.name}'{at} must be one of {', '.join(spec.choices)}, got {value!r}")
        return value
    if spec.min is not None:
        if value < spec.min or (spec.min_exclusive and value == spec.min):
            op = ">" if spec.min_exclusive else ">="
            raise ParamError(f"parameter '{spec.name}'{at} must be {op} {spec.min:g}, got {value!r}")
    if spec.max is not None and value > spec.max:
        raise ParamError(f"parameter '{spec.name}'{at} must be <= {spec.max:g}, got {value!r}")
    return value


@dataclass(frozen=True)
class RobotinoParams:
    """Physical parameters of the Robotino (SI units), as in config/*.yaml.

    `M` and `J` are the effective mass and yaw inertia the body equations
    (eqs. 1-9) use: the body's plus the three rotors' inertia reflected through
    the gear (no-slip wheels: per wheel J_rotor gear^2 / r^2 along its drive
    direction; the three directions sum to 1.5 I in the plane and to 3 l^2 in yaw).
    """

    mass_kg: float
    yaw_inertia_kg_m2: float
    wheel_radius_m: float
    wheel_distance_m: float
    gear_ratio: float
    body_friction_x_n_s_per_m: float
    body_friction_y_n_s_per_m: float
    body_friction_theta_n_m_s: float
    resistance_ohm: float
    inductance_h: float
    torque_constant_n_m_per_a: float
    rotor_inertia_kg_m2: float
    viscous_friction_n_m_s: float
    nominal_current_a: float
    supply_voltage_v: float
    nominal_speed_rpm: float

    @property
    def rotor_mass_equivalent_kg(self) -> float:
        """Rotor inertia seen at one wheel's rim, J_rotor gear^2 / r^2."""
        return self.rotor_inertia_kg_m2 * self.gear_ratio**2 / self.wheel_radius_m**2

    @property
    def M(self) -> float:
        """Effective translational mass (body + reflected rotors)."""
        return self.mass_kg + 1.5 * self.rotor_mass_equivalent_kg

    @property
    def J(self) -> float:
        """Effective yaw inertia (body + reflected rotors)."""
        return self.yaw_inertia_kg_m2 + 3.0 * self.wheel_distance_m**2 * self.rotor_mass_equivalent_kg

    @property
    def k_x(self) -> float:
        return self.body_friction_x_n_s_per_m

    @property
    def k_y(self) -> float:
        return self.body_friction_y_n_s_per_m

    @property
    def k_theta(self) -> float:
        return self.body_friction_theta_n_m_s

    @property
    def r(self) -> float:
        return self.wheel_radius_m

    @property
    def l(self) -> float:  # noqa: E743 - the paper's name
        return self.wheel_distance_m

    @property
    def tau_electrical_s(self) -> float:
        """Electrical time constant L / R of a drive."""
        return self.inductance_h / self.resistance_ohm

    def scaled(self, mass: float = 1.0, inertia: float = 1.0, friction: float = 1.0) -> RobotinoParams:
        """A copy with mass, yaw inertia and body friction multiplied (for mismatch studies)."""
        return replace(
            self,
            mass_kg=self.mass_kg * mass,
            yaw_inertia_kg_m2=self.yaw_inertia_kg_m2 * inertia,
            body_friction_x_n_s_per_m=self.body_friction_x_n_s_per_m * friction,
            body_friction_y_n_s_per_m=self.body_friction_y_n_s_per_m * friction,
            body_friction_theta_n_m_s=self.body_friction_theta_n_m_s * friction,
        )


@dataclass(frozen=True)
class ControlParams:
    """Controller settings: period, horizon, per-axis weights, mode, odometry filter and twist, current limit."""

    period_s: float
    horizon: int
    q_x: float
    q_y: float
    q_theta: float
    r_x: float
    r_y: float
    r_theta: float
    mode: str
    odometry_filter_time_constant_s: float
    odometry_twist: str
    current_limit_a: float

    @property
    def q(self) -> tuple[float, float, float]:
        """Output weights (x, y, theta)."""
        return (self.q_x, self.q_y, self.q_theta)

    @property
    def r(self) -> tuple[float, float, float]:
        """Input-increment weights (x, y, theta)."""
        return (self.r_x, self.r_y, self.r_theta)


def preset_file(name: str) -> Path:
    """Path of a shipped preset (`robotino3`, `robotino2`)."""
    return config_file(f"{name}.yaml")


def config_file(filename: str) -> Path:
    """Path of a file shipped in config/.

    Looks in the installed share directory (ament index) first, then in the
    source tree's config/ folder.
    """
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("robotino_geom_mpc")) / "config")
    except Exception:  # not installed as an ament package, or AMENT_PREFIX_PATH unset
        pass
    candidates.append(Path(__file__).resolve().parents[2] / "config")
    for folder in candidates:
        path = folder / filename
        if path.is_file():
            return path
    raise ParamError(f"'{filename}' not found in {', '.join(map(str, candidates))}")


def default_params_file() -> Path:
    """The default preset (Robotino 3)."""
    return preset_file("robotino3")


class _RclLoader(yaml.SafeLoader):
    """YAML as rcl reads parameter files: ``1e6`` and ``-2.5E-3`` are numbers (YAML 1.1 wants a dot)."""


_RclLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:[0-9][0-9_]*)?\.?[0-9]*[eE][-+]?[0-9]+$"), list("-+0123456789.")
)


def _flatten(tree: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


def _sections(path: Path, tree: dict, prefix: str = "") -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for key, body in tree.items():
        name = f"{prefix}{key}"
        if isinstance(body, dict) and "ros__parameters" in body and isinstance(body["ros__parameters"], dict):
            out[name] = _flatten(body["ros__parameters"])
        elif isinstance(body, dict) and body and "ros__parameters" not in body and all(
            isinstance(v, dict) for v in body.values()
        ):
            out.update(_sections(path, body, name.rstrip("/") + "/"))  # a namespace level
        else:
            raise ParamError(f"{path}: section '{name}' must contain a 'ros__parameters' mapping")
    return out


def parse_parameter_file(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """Every section of a ROS 2 parameter file: node name (namespaces joined by '/') -> flat dotted values.

    Raises
    ------
    ParamError
        If the file cannot be read, is not YAML, or is not in the
        ``node_name: ros__parameters:`` form.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ParamError(f"cannot read parameter file {path}: {exc.strerror or exc}") from None
    try:
        doc = yaml.load(text, Loader=_RclLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" at line {mark.line + 1}" if mark is not None else ""
        raise ParamError(f"{path}{line}: not valid YAML") from None
    if not isinstance(doc, dict):
        raise ParamError(f"{path}: expected a mapping of node names to 'ros__parameters'")
    return _sections(path, doc)


def read_parameter_file(path: str | os.PathLike, node: str | None = None) -> dict[str, Any]:
    """Read a ROS 2 parameter file into flat dotted names.

    The `/**` section applies to every node; the section named `node` (if
    given and present) overrides it, as rcl does.

    Raises
    ------
    ParamError
        As `parse_parameter_file`, or if neither section is there.
    """
    sections = parse_parameter_file(path)
    values: dict[str, Any] = {}
    for section in ("/**", node):
        values.update(sections.get(section, {}) if section is not None else {})
    if not values:
        raise ParamError(f"{path}: no '/**' section with 'ros__parameters' found")
    return values


def _build(cls: type, specs: tuple[ParamSpec, ...], values: dict[str, Any], where: str) -> Any:
    kwargs = {}
    for spec in specs:
        if spec.name not in values:
            raise ParamError(f"parameter '{spec.name}' missing in {where}")
        kwargs[spec.attr] = validate_value(spec, values[spec.name], where)
    assert set(kwargs) == {f.name for f in fields(cls)}
    return cls(**kwargs)


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
        as a node checks it (`core.param_files.check_parameter_files`).
    """
    from robotino_geom_mpc.core.param_files import check_parameter_files  # (it imports this module)

    path = Path(path) if path is not None else default_params_file()
    check_parameter_files([path])
    values = read_parameter_file(path, node)
    where = str(path)
    return _build(RobotinoParams, ROBOT_SPECS, values, where), _build(ControlParams, CONTROL_SPECS, values, where)


def params_from_values(values: dict[str, Any], where: str = "parameters") -> tuple[RobotinoParams, ControlParams]:
    """Build validated parameters from flat dotted names (e.g. a ROS node's parameters)."""
    return _build(RobotinoParams, ROBOT_SPECS, values, where), _build(ControlParams, CONTROL_SPECS, values, where)

