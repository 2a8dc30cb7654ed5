"""ROS parameters declared from the `params.specs` specs: descriptor, range, default, validation on start and on set.

Each parameter gets a `ParameterDescriptor` with its description, unit and
range, its default from the default preset (`params.presets.default_params_file()`),
and is validated on start and on every set; a refused set keeps the old value.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from robotino_geom_mpc.params.specs import (
    ALL_SPECS,
    ParamError,
    ParamSpec,
    params_from_values,
    validate_value,
)
from robotino_geom_mpc.params.files import read_parameter_file
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.errors import RobotinoError

__all__ = ["NodeStartError", "SpecParameters", "preset_defaults", "spec_defaults"]

_INT_BOUND = 2**62


class NodeStartError(RobotinoError, RuntimeError):
    """A node cannot start: a parameter is missing, mistyped or out of range."""


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    unit = f" [{spec.unit}]" if spec.unit else ""
    desc = ParameterDescriptor(description=f"{spec.description}{unit}")
    constraints = []
    if spec.min is not None or spec.max is not None:
        low = spec.min if spec.min is not None else -math.inf
        high = spec.max if spec.max is not None else math.inf
        if spec.type is float:
            desc.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
        elif spec.type is int:
            desc.integer_range = [
                IntegerRange(
                    from_value=int(max(low, -_INT_BOUND)),
                    to_value=int(min(high, _INT_BOUND)),
                    step=1,
                )
            ]
        if spec.min is not None and spec.min_exclusive:
            constraints.append(f"> {spec.min:g}")
    if spec.choices:
        constraints.append("one of " + ", ".join(spec.choices))
    desc.additional_constraints = "; ".join(constraints)
    return desc


class SpecParameters:
    """The parameters of one node, declared from specs and validated on start and on set.

    Parameters
    ----------
    node
        The node that declares them.
    specs
        The specs (the robot and control specs plus the node's own).
    defaults
        Default value per name; the robot/control defaults come from the
        default preset when not given.
    on_change
        Called after a successful set with the values it changed (name: new value); a set to the
        current values (``ros2 param load`` of the same file) changes nothing and calls nothing.
    fixed
        Names that cannot change while the node runs (a set is refused with that reason).
    check
        Called with the complete candidate values (the current values updated by
        a set) on every set and once at start; a returned string refuses the set
        with that reason (the node keeps its values), or at start stops the node.

    Raises
    ------
    NodeStartError
        When an override (from --params-file or -p) is mistyped or out of range,
        or `check` refuses the start values.
    """

    def __init__(
        self,
        node: Node,
        specs: Iterable[ParamSpec],
        defaults: dict[str, Any],
        on_change: Callable[[dict[str, Any]], None] | None = None,
        fixed: tuple[str, ...] = (),
        check: Callable[[dict[str, Any]], str | None] | None = None,
    ) -> None:
        self._node = node
        self._fixed = fixed
        self._check = check
        self.specs = {s.name: s for s in specs}
        self._on_change = on_change
        self.values: dict[str, Any] = {}
        for name, spec in self.specs.items():
            if name not in defaults:
                raise NodeStartError(f"no default for parameter '{name}'")
            try:
                param = node.declare_parameter(name, defaults[name], _descriptor(spec))
            except Exception as exc:  # rclpy's type/range exceptions at declaration
                raise NodeStartError(f"parameter '{name}': {exc}") from None
            try:
                self.values[name] = validate_value(spec, param.value, "the node's parameters")
            except ParamError as exc:
                raise NodeStartError(str(exc)) from None
        reason = self._checked(dict(self.values))
        if reason is not None:
            raise NodeStartError(reason)
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._applied)

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    def _checked(self, values: dict[str, Any]) -> str | None:
        """The `check`'s reason to refuse `values`; a check that raises refuses them too (never a crash)."""
        if self._check is None:
            return None
        try:
            return self._check(values)
        except Exception as exc:  # e.g. a LinAlgError of a stability check on extreme values
            return f"the parameter check failed on these values: {type(exc).__name__}: {exc}"

    def _validate(self, params: list[Parameter]) -> SetParametersResult:
        candidate = dict(self.values)
        for param in params:
            spec = self.specs.get(param.name)
            if spec is None:
                continue  # use_sim_time and other parameters rclpy owns
            if param.name in self._fixed:
                return SetParametersResult(
                    successful=False, reason=f"parameter '{param.name}' cannot change while the node runs; restart it"
                )
            try:
                candidate[param.name] = validate_value(spec, param.value, "set request")
            except ParamError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        reason = self._checked(candidate)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _applied(self, params: list[Parameter]) -> None:
        accepted = {p.name: validate_value(self.specs[p.name], p.value) for p in params if p.name in self.specs}
        changed = {name: value for name, value in accepted.items() if value != self.values[name]}
        if not changed:
            return
        self.values.update(changed)
        if self._on_change is not None:
            self._on_change(changed)

    def robot_control(self):
        """The validated `(RobotinoParams, ControlParams)` of the current values."""
        return params_from_values(self.values, f"parameters of node '{self._node.get_name()}'")


def preset_defaults() -> dict[str, Any]:
    """Robot and control defaults: the `/**` section of the default preset."""
    return read_parameter_file(default_params_file())


def spec_defaults(specs: Iterable[ParamSpec] = ALL_SPECS) -> dict[str, Any]:
    """Defaults of the robot/control specs from the default preset."""
    values = preset_defaults()
    return {s.name: values[s.name] for s in specs}
