"""Shared ROS 2 plumbing of the nodes: parameters from the spec, QoS profiles, message conversions, main loop.

Parameters are declared from `core.params` specs (`ParamSpec`): each gets a
`ParameterDescriptor` with its description, unit and range, its default from
the default preset (`core.params.default_params_file()`), and is validated on
start and on every set; a refused set keeps the old value.

QoS, chosen on purpose:

* `CONTROL_QOS`, the subscriptions of the control loop (odom,
  wheel_voltages, reference_preview): reliable (a lockstep tick must never
  be lost), keep-last with a small depth (the newest sample is what matters;
  a short queue bounds latency but holds the previews of two ticks in
  flight), volatile (old control data is useless to a late joiner).
* `PUBLISH_QOS`, every publisher of the loop (the same plus wheel_currents,
  joint_states, ground_truth/odom, diagnostics, /clock): the same policies
  with a deeper writer history, so a slow reader such as the recorder can
  lag some ticks behind without losing samples (keep-last never blocks the
  loop).
* `LATCHED_QOS` (reference_path): reliable, keep-last 1, transient local, so
  a visualiser or recorder that starts late still gets the whole reference.
* `CLOCK_SUB_QOS`: the trajectory's own /clock subscription, reliable so no
  lockstep tick is missed (the plant's reliable /clock publisher also serves
  the best-effort subscription of rclpy's time source).
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from pathlib import Path
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import Quaternion
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from robotino_geom_mpc.core.params import (
    ALL_SPECS,
    ParamError,
    ParamSpec,
    params_from_values,
    read_parameter_file,
    default_params_file,
    validate_value,
)

__all__ = [
    "CONTROL_QOS",
    "PUBLISH_QOS",
    "LATCHED_QOS",
    "CLOCK_SUB_QOS",
    "NodeStartError",
    "SpecParameters",
    "preset_defaults",
    "spec_defaults",
    "stamp_to_ns",
    "ns_to_stamp",
    "yaw_to_quaternion",
    "quaternion_to_yaw",
    "unwrap_near",
    "all_finite",
    "run_node",
    "monotonic",
]

CONTROL_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
PUBLISH_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
CLOCK_SUB_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

_INT_BOUND = 2**62


class NodeStartError(RuntimeError):
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
        Called with the dict of accepted new values after a successful set.
    fixed
        Names that cannot change while the node runs (a set is refused with that reason).

    Raises
    ------
    NodeStartError
        When an override (from --params-file or -p) is mistyped or out of range.
    """

    def __init__(
        self,
        node: Node,
        specs: Iterable[ParamSpec],
        defaults: dict[str, Any],
        on_change: Callable[[dict[str, Any]], None] | None = None,
        fixed: tuple[str, ...] = (),
    ) -> None:
        self._node = node
        self._fixed = fixed
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
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._applied)

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    def _validate(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            spec = self.specs.get(param.name)
            if spec is None:
                continue  # use_sim_time and other parameters rclpy owns
            if param.name in self._fixed:
                return SetParametersResult(
                    successful=False, reason=f"parameter '{param.name}' cannot change while the node runs; restart it"
                )
            try:
                validate_value(spec, param.value, "set request")
            except ParamError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _applied(self, params: list[Parameter]) -> None:
        changed = {p.name: validate_value(self.specs[p.name], p.value) for p in params if p.name in self.specs}
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


def stamp_to_ns(stamp: TimeMsg) -> int:
    """builtin_interfaces/Time as integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def ns_to_stamp(ns: int) -> TimeMsg:
    """Integer nanoseconds as builtin_interfaces/Time."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return TimeMsg(sec=sec, nanosec=nanosec)


def yaw_to_quaternion(theta: float) -> Quaternion:
    """Rotation about z by `theta` (rad)."""
    half = 0.5 * theta
    return Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))


def quaternion_to_yaw(q: Quaternion) -> float:
    """Yaw (rad, in (-pi, pi]) of a quaternion (ZYX convention)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def unwrap_near(angle: float, reference: float) -> float:
    """`angle + 2 pi k` closest to `reference` (continuous yaw from a wrapped one)."""
    return angle + 2.0 * math.pi * round((reference - angle) / (2.0 * math.pi))


def all_finite(values: Iterable[float]) -> bool:
    """True when every value is a finite float."""
    return bool(np.all(np.isfinite(np.fromiter(values, dtype=float))))


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Init rclpy, build the node, spin it with the events executor, exit quietly on SIGINT/SIGTERM.

    SIGINT and SIGTERM only set a flag the spin loop checks (at least every
    0.1 s), so no callback is interrupted half-way and no traceback is
    printed. A node that ends its own run sets a `Future` attribute ``done``
    and may set ``exit_status``. A `NodeStartError` (bad parameter) is
    reported in one line on stderr with exit status 2. Returns the exit status.
    """
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    stop = threading.Event()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = None
    status = 0
    try:
        node = factory()
        executor = EventsExecutor()
        executor.add_node(node)
        done = getattr(node, "done", None)
        while not stop.is_set() and rclpy.ok() and not (done is not None and done.done()):
            executor.spin_once(timeout_sec=0.1)
        status = getattr(node, "exit_status", 0)
        if done is not None and done.done():  # a finished run: let the last samples reach every reader
            for pub in node.publishers:
                pub.wait_for_all_acked(Duration(seconds=1.0))
    except NodeStartError as exc:
        print(f"{Path(sys.argv[0]).name.removesuffix('.py')}: error: {exc}", file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return status


def monotonic() -> float:
    """Steady time in seconds (watchdogs and latency; never the ROS clock)."""
    return time.monotonic()
