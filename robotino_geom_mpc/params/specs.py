"""Parameters of the Robotino and of its controller: the one spec of every name, type, unit, range and description.

The spec (`ROBOT_SPECS`, `CONTROL_SPECS`) is the single source of truth for
names, types, ranges and descriptions: the loader validates a YAML file
against it and the ROS nodes declare their parameters from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any


from robotino_geom_mpc.errors import RobotinoError

__all__ = [
    "LOOP_SPECS",
    "RECORDED_CONTROLLER_SPECS",
    "TWIST_MODELS",
    "ParamSpec",
    "ParamError",
    "ROBOT_SPECS",
    "CONTROL_SPECS",
    "ALL_SPECS",
    "CHAIN_ACTIVE_SPEC",
    "CHAIN_SPECS",
    "RobotinoParams",
    "ControlParams",
    "params_from_values",
    "validate_value",
]


TWIST_MODELS = ("instantaneous", "period_mean")
"""How the odometry's twist was measured (`OdometryFilter`'s predictor): the velocity at the measurement's
instant (a state estimate, the simulated ideal odometry) or its mean over the interval since the previous
measurement (wheel-encoder count differences, as the Robotino's odometry and `robotino_geom_mpc.model.encoders`)."""


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
    ParamSpec("robot.body_friction_theta_n_m_s", float, "Body viscous friction k_theta (eq. 3)", "N m s", 0.0, 1e4,
              False),
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
    ParamSpec("control.r_theta", float, "Input-increment weight R_p of the theta MPC (eq. 54)", "s^4/rad^2", 0.0, 1e15,
              True),
    ParamSpec(
        "control.mode",
        str,
        "closed_form: unconstrained MPC (eq. 56); constrained: QP with wheel current and voltage limits",
        choices=("closed_form", "constrained"),
    ),
    ParamSpec(
        "control.odometry_filter_time_constant_s",
        float,
        "Time constant tau of the odometry pose filter (control.estimator): the position the MPCs see follows the "
        "measured pose through a first-order lag tau, carried by the measured velocity; 0 = raw pose (the paper)",
        "s",
        0.0,
        60.0,
        False,
    ),
    ParamSpec(
        "control.odometry_twist",
        str,
        "How the odometry's twist is measured, hence the pose filter's predictor (control.estimator): "
        "instantaneous (velocity at the stamp: trapezoid) or period_mean (mean since the previous message, "
        "as wheel-encoder odometry: the pose advance that built the measured pose)",
        choices=TWIST_MODELS,
    ),
    ParamSpec(
        "control.current_limit_a",
        float,
        "Wheel current limit of the closed-form mode (control.inverse_drive.InverseDrive.limited_step): when a wheel's "
        "period-average or end current would exceed it, or a voltage the supply, the commanded accelerations u are "
        "scaled by one factor (direction kept); 0 = no limit, voltages clipped per wheel (the paper)",
        "A",
        0.0,
        100.0,
        False,
    ),
    ParamSpec(
        "control.plan_length",
        int,
        "Periods M of each command plan an off-board controller sends (control.delay_compensation): the robot's "
        "buffer runs on the last plan through that many periods of lost or late plans",
        "periods",
        1,
        200,
        False,
    ),
    ParamSpec(
        "control.lead_min_periods",
        int,
        "Smallest lead of a plan (its first command acts this many periods after the odometry it was made from)",
        "periods",
        0,
        200,
        False,
    ),
    ParamSpec(
        "control.lead_max_periods",
        int,
        "Largest lead of a plan: round trips beyond it make plans start late (the robot then runs the previous one)",
        "periods",
        0,
        200,
        False,
    ),
    ParamSpec(
        "control.lead_quantile",
        float,
        "Quantile of the measured round trips (robot's receipt of a plan - its odometry's stamp) the lead covers",
        "",
        0.5,
        1.0,
        False,
    ),
)

ALL_SPECS: tuple[ParamSpec, ...] = ROBOT_SPECS + CONTROL_SPECS

# The real robot's driver and firmware chain (model.driver_chain; sources: docs/howto/real_robotino.md)
_LOGISTICS = "robocup-logistics/ros2-robotino"
_CONTROLD = "Festo controld3 (shipped with the driver)"

CHAIN_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("chain.odometry_rate_hz", float, f"rate at which the firmware integrates and sends odometry, "
              f"without a stamp ({_CONTROLD})", "Hz", 1.0, 1000.0, False),
    ParamSpec("chain.driver_rate_hz", float, f"rate of the driver node's loop: odometry dispatch and cmd_vel "
              f"forwarding ({_LOGISTICS})", "Hz", 1.0, 1000.0, False),
    ParamSpec("chain.driver_phase_s", float, "offset of the driver's loop after a firmware tick (unknown on a real "
              "robot: any value in [0, 1 / driver_rate_hz))", "s", 0.0, 1.0, False),
    ParamSpec("chain.odometry_dispatch", str, f"all: every odometry that arrived since the last pass is dispatched; "
              f"latest: only the newest ({_LOGISTICS})", choices=("all", "latest")),
    ParamSpec("chain.tick_s", float, f"firmware tick on which commands are applied and odometry sampled "
              f"({_CONTROLD})", "s", 1e-3, 1.0, False),
    ParamSpec("chain.ramp_translation_m_s2", float, f"acceleration ramp of the commanded translation "
              f"(vector norm) ({_CONTROLD} configuration)", "m/s^2", 0.01, 100.0, False),
    ParamSpec("chain.ramp_rotation_rad_s2", float, f"acceleration ramp of the commanded rotation ({_CONTROLD} "
              f"configuration: 180 deg/s^2)", "rad/s^2", 0.01, 1000.0, False),
    ParamSpec("chain.max_translation_m_s", float, f"largest commanded translation speed ({_CONTROLD} "
              f"configuration)", "m/s", 0.01, 10.0, False),
    ParamSpec("chain.max_rotation_rad_s", float, f"largest commanded rotation speed ({_CONTROLD} configuration: "
              f"90 deg/s)", "rad/s", 0.01, 100.0, False),
    ParamSpec("chain.motor_timeout_s", float, f"the firmware stops the motors this long after the last "
              f"command ({_CONTROLD})", "s", 0.01, 60.0, False),
    ParamSpec("chain.speed_floor", str, f"enabled: the driver raises any non-zero speed below the floor to it "
              f"({_LOGISTICS}); disabled: forwarded as is", choices=("enabled", "disabled")),
    ParamSpec("chain.speed_floor_translation_m_s", float, f"the driver's floor of a non-zero translation "
              f"component ({_LOGISTICS})", "m/s", 0.0, 1.0, False),
    ParamSpec("chain.speed_floor_rotation_rad_s", float, f"the driver's floor of a non-zero rotation "
              f"({_LOGISTICS})", "rad/s", 0.0, 10.0, False),
    ParamSpec("chain.speed_loop_time_constant_s", float, "time constant of the wheels' PI speed loops on the "
              "base's microcontroller (model.speed_loop.tuned_gains; order of magnitude, not published)", "s",
              1e-3, 1.0, False),
    ParamSpec("chain.link.delay_s", float, "fixed one-way delay of the driver <-> robot link (WiFi when the "
              "driver runs off-board; 0 on the robot's PC), each direction (network.link)", "s", 0.0, 1.0, False),
    ParamSpec("chain.link.jitter_s", float, "plus a uniform draw in [0, jitter_s] per message, each direction",
              "s", 0.0, 1.0, False),
    ParamSpec("chain.link.loss", float, "probability that a message is lost, each direction", "", 0.0, 0.5, False),
)

# the controller loop's own settings as node parameters (`loop.controller_loop.LoopSettings`, same names): the
# controller node declares them, a recorder stores them for the replays
LOOP_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("odom_timeout_s", float, "Odometry older than this (arrival, and stamp against the node clock in "
              "realtime) is stale: zero volts", "s", 0.0, 60.0, True),
    ParamSpec("reference_timeout_s", float, "Reference preview older than this (arrival, and stamp against the node "
              "clock in realtime) is stale: zero volts", "s", 0.0, 60.0, True),
    ParamSpec("future_tolerance_s", float, "Realtime: an input stamped further ahead of the node clock is refused",
              "s", 0.0, 60.0, False),
    ParamSpec("quaternion_norm_tolerance", float, "An odometry or preview quaternion whose norm differs from 1 by more "
              "(relative) is refused", "", 0.0, 0.5, True),
    ParamSpec("tilt_tolerance_rad", float, "An odometry or preview orientation with more roll/pitch (tilt of the z "
              "axis) is refused", "rad", 0.0, 0.5 * math.pi, True),
    ParamSpec("reference_jump_m", float, "A preview whose reference position moved by more than this from the "
              "previous preview (moved to its stamp) restarts the tracking bumplessly", "m", 0.0, 1e3, True),
    ParamSpec("reference_jump_rad", float, "The same for the reference heading", "rad", 0.0, 1e3, True),
    ParamSpec("blend_acceleration_mps2", float, "Bound on |(x'', y'')| of the bumpless-restart offset (its duration "
              "is the shortest that meets it)", "m/s^2", 0.0, 100.0, True),
    ParamSpec("blend_acceleration_radps2", float, "Bound on |theta''| of the bumpless-restart offset", "rad/s^2", 0.0,
              1000.0, True),
)

CHAIN_ACTIVE_SPEC = ParamSpec(
    "chain.active", str, "enabled: the plant node behaves as the driver + firmware chain chain.* (realtime, cmd_vel) "
    "and the controller controls through it (control.chain_controller: reconstructed measurement times, the command "
    "path predicted, ramp-respecting velocities); disabled: neither", choices=("disabled", "enabled"))

# the controller's parameters a recorder stores beside the robot's and the control's (given by the launch and `run`
# the values they give the controller): what the replays need of it besides its model
RECORDED_CONTROLLER_SPECS: tuple[ParamSpec, ...] = (*CHAIN_SPECS, CHAIN_ACTIVE_SPEC, *LOOP_SPECS)


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
    """Controller settings: period, horizon, per-axis weights, mode, odometry filter and twist, current limit, and
    the plans of an off-board controller (length, lead bounds and quantile; unused without a link).
    """

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
    plan_length: int = 25
    lead_min_periods: int = 0
    lead_max_periods: int = 30
    lead_quantile: float = 0.99

    @property
    def q(self) -> tuple[float, float, float]:
        """Output weights (x, y, theta)."""
        return (self.q_x, self.q_y, self.q_theta)

    @property
    def r(self) -> tuple[float, float, float]:
        """Input-increment weights (x, y, theta)."""
        return (self.r_x, self.r_y, self.r_theta)


def _build(cls: type, specs: tuple[ParamSpec, ...], values: dict[str, Any], where: str) -> Any:
    kwargs = {}
    for spec in specs:
        if spec.name not in values:
            raise ParamError(f"parameter '{spec.name}' missing in {where}")
        kwargs[spec.attr] = validate_value(spec, values[spec.name], where)
    assert set(kwargs) == {f.name for f in fields(cls)}
    return cls(**kwargs)


def params_from_values(values: dict[str, Any], where: str = "parameters") -> tuple[RobotinoParams, ControlParams]:
    """Build validated parameters from flat dotted names (e.g. a ROS node's parameters)."""
    return _build(RobotinoParams, ROBOT_SPECS, values, where), _build(ControlParams, CONTROL_SPECS, values, where)

