"""The real Robotino's command and odometry chain (driver + firmware) as parameters and its pieces (no rclpy).

What sits between a ROS ``cmd_vel`` and the wheels on a Robotino 3/4 driven by the robocup-logistics
ros2-robotino driver (read from its code and Festo's daemons; docs/robotino.md, "The real robot's chain",
with the sources at a named commit; docs/howto/real_robotino.md):

* the driver node spins in a loop at ``driver_rate_hz`` (30 Hz). At each pass it dispatches the odometry
  that arrived since the previous pass, stamped with its own clock at dispatch (the firmware sends none),
  and forwards each ``cmd_vel`` received since the previous pass once (never re-sent; no timeout of its own),
  with any non-zero component below the speed floor raised to the floor (`speed_floor`);
* between driver and robot: the link of the networked-control issue (API2 over the robot's WiFi), one
  per direction (``link.*``);
* on the robot, ``controld3`` applies the newest received command on its ``tick_s`` (20 ms) tick, through
  the acceleration ramps and maxima (`Firmware.tick`), stops the motors ``motor_timeout_s`` after the last
  command, and integrates odometry at ``odometry_rate_hz`` (50 Hz, on the same tick);
* per motor, PI speed loops on the base's microcontroller (`model.speed_loop`), here tuned to a first-order
  loop of ``speed_loop_time_constant_s``.

`params.specs.CHAIN_SPECS` names each number (``chain.*``) with its unit, range and source; `CHAIN_PRESETS` holds the
robocup-logistics preset; `chain_params` builds and checks a `ChainParams` (out-of-range values are refused
with their names). The event loop that runs a plant through all of this is `model.chain_emulation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.params.specs import CHAIN_ACTIVE_SPEC, CHAIN_SPECS, ParamError, validate_value

__all__ = [
    "CHAIN_NODE_DEFAULTS",
    "CHAIN_NODE_SPECS",
    "CHAIN_PRESETS",
    "ChainError",
    "ChainParams",
    "Firmware",
    "chain_params",
    "speed_floor",
]


class ChainError(RobotinoError, ValueError):
    """A chain parameter out of range or of the wrong type (the message names it), or a bad command."""


_ATTR = {spec.name: spec.name.removeprefix("chain.").replace(".", "_") for spec in CHAIN_SPECS}


@dataclass(frozen=True)
class ChainParams:
    """The chain's numbers (`CHAIN_SPECS` gives each one's unit, range and source); defaults: robocup-logistics."""

    odometry_rate_hz: float = 50.0
    driver_rate_hz: float = 30.0
    driver_phase_s: float = 0.007
    odometry_dispatch: str = "all"
    tick_s: float = 0.02
    ramp_translation_m_s2: float = 0.4
    ramp_rotation_rad_s2: float = math.pi
    max_translation_m_s: float = 1.0
    max_rotation_rad_s: float = 0.5 * math.pi
    motor_timeout_s: float = 0.5
    speed_floor: str = "enabled"
    speed_floor_translation_m_s: float = 0.02
    speed_floor_rotation_rad_s: float = 0.07
    speed_loop_time_constant_s: float = 0.025
    link_delay_s: float = 0.0
    link_jitter_s: float = 0.0
    link_loss: float = 0.0

    @property
    def driver_period_s(self) -> float:
        """The driver loop's period [s]."""
        return 1.0 / self.driver_rate_hz

    @property
    def odometry_period_s(self) -> float:
        """The firmware odometry's period [s]."""
        return 1.0 / self.odometry_rate_hz

    def values(self) -> dict[str, Any]:
        """The parameters by their ``chain.*`` names (a ROS parameter file's flat form)."""
        return {name: getattr(self, attr) for name, attr in _ATTR.items()}


assert set(_ATTR.values()) == {f.name for f in fields(ChainParams)}

CHAIN_PRESETS: dict[str, dict[str, Any]] = {
    # robocup-logistics/ros2-robotino on a Robotino 3/4, driver on the robot's PC or next to its access point
    "robocup-logistics": ChainParams().values(),
}


# the nodes' chain parameters (plant: emulate the chain; controller: control through it), the preset's defaults
CHAIN_NODE_SPECS = (CHAIN_ACTIVE_SPEC,) + CHAIN_SPECS
CHAIN_NODE_DEFAULTS = {CHAIN_ACTIVE_SPEC.name: "disabled", **CHAIN_PRESETS["robocup-logistics"]}


def chain_params(values: dict[str, Any] | None = None, preset: str = "robocup-logistics",
                 where: str = "chain parameters") -> ChainParams:
    """A checked `ChainParams`: `preset`'s values overridden by `values` (``chain.*`` names).

    Raises
    ------
    ChainError
        An unknown preset or name, a wrong type or a value out of its range, named; or an odometry tick that
        is not a whole number of firmware ticks.
    """
    if preset not in CHAIN_PRESETS:
        raise ChainError(f"unknown chain preset {preset!r}; known: {', '.join(CHAIN_PRESETS)}")
    merged = dict(CHAIN_PRESETS[preset])
    for name, value in (values or {}).items():
        if name not in _ATTR:
            raise ChainError(f"unknown chain parameter {name!r}; known: {', '.join(_ATTR)}")
        merged[name] = value
    specs = {spec.name: spec for spec in CHAIN_SPECS}
    try:
        checked = {_ATTR[name]: validate_value(specs[name], value, where) for name, value in merged.items()}
    except ParamError as exc:
        raise ChainError(str(exc)) from None
    params = ChainParams(**checked)
    ratio = params.odometry_period_s / params.tick_s
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ChainError(f"parameter 'chain.odometry_rate_hz' ({params.odometry_rate_hz:g} Hz) must give a whole "
                         f"number of firmware ticks (chain.tick_s = {params.tick_s:g} s)")
    if params.driver_phase_s >= params.driver_period_s:
        raise ChainError(f"parameter 'chain.driver_phase_s' must be < 1 / chain.driver_rate_hz, "
                         f"got {params.driver_phase_s!r}")
    return params


def speed_floor(twist: tuple[float, float, float], params: ChainParams) -> tuple[float, float, float]:
    """The twist the driver forwards: each non-zero component below its floor raised to it (sign kept).

    With ``speed_floor`` disabled the twist is returned as it is.
    """
    vx, vy, w = twist
    if params.speed_floor == "disabled":
        return vx, vy, w

    def floored(v: float, floor: float) -> float:
        return math.copysign(floor, v) if 0.0 < abs(v) < floor else v

    translation, rotation = params.speed_floor_translation_m_s, params.speed_floor_rotation_rad_s
    return floored(vx, translation), floored(vy, translation), floored(w, rotation)


class Firmware:
    """``controld3``'s command path: the newest command through the maxima and ramps, once per tick.

    The setpoint (v_x, v_y, theta') in base_link moves towards the target by at most
    ``ramp_translation_m_s2 tick_s`` (translation, as a vector: its direction kept) and
    ``ramp_rotation_rad_s2 tick_s`` (rotation) per tick; the target is the newest command, its translation
    clipped to ``max_translation_m_s`` (norm) and its rotation to ``max_rotation_rad_s``, or zero once
    ``motor_timeout_s`` has passed since that command arrived.
    """

    def __init__(self, params: ChainParams) -> None:
        self.params = params
        self.setpoint = (0.0, 0.0, 0.0)
        self.target = (0.0, 0.0, 0.0)
        self.received_s: float | None = None

    def receive(self, twist: tuple[float, float, float], time_s: float) -> None:
        """A command arrives (the newest one wins at the next tick)."""
        if len(twist) != 3 or not all(math.isfinite(v) for v in twist):
            raise ChainError(f"a command must be three finite numbers, got {twist!r}")
        p = self.params
        vx, vy, w = (float(v) for v in twist)
        speed = math.hypot(vx, vy)
        if speed > p.max_translation_m_s:
            vx, vy = vx * p.max_translation_m_s / speed, vy * p.max_translation_m_s / speed
        self.target = (vx, vy, max(-p.max_rotation_rad_s, min(p.max_rotation_rad_s, w)))
        self.received_s = time_s

    def timed_out(self, time_s: float) -> bool:
        """True when no command arrived within ``motor_timeout_s`` before `time_s` (or none at all)."""
        return self.received_s is None or time_s - self.received_s >= self.params.motor_timeout_s - 1e-12

    def tick(self, time_s: float) -> tuple[float, float, float]:
        """The setpoint the speed loops hold from the tick at `time_s` to the next one."""
        p = self.params
        tx, ty, tw = (0.0, 0.0, 0.0) if self.timed_out(time_s) else self.target
        sx, sy, sw = self.setpoint
        dx, dy = tx - sx, ty - sy
        step = math.hypot(dx, dy)
        limit = p.ramp_translation_m_s2 * p.tick_s
        if step > limit:
            dx, dy = dx * limit / step, dy * limit / step
        limit = p.ramp_rotation_rad_s2 * p.tick_s
        dw = max(-limit, min(limit, tw - sw))
        self.setpoint = (sx + dx, sy + dy, sw + dw)
        return self.setpoint
