"""A recording's topics and their messages in publish-time order: what the report, the link figures and the
replays (`regress`, `regress_plans`, `regress_chain`) all read a bag with.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any, Literal, overload

from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import RUN_METADATA, BagError, BagMessage
from robotino_geom_mpc.recording.definitions import _typestore
from robotino_geom_mpc.ros.cdr import diagnostics_with
from robotino_geom_mpc.ros.decode import diagnostics_with_of_message, stamp_ns

__all__ = ["find_topic", "plan_topic", "converted_by_publish_time", "by_publish_time", "TRACKING_KEY",
           "read_controller_diagnostics", "controller_diagnostics_of_message", "controller_diagnostics", "stamp_ns",
           "run_parameters", "CONTROLLER_NODE", "controller_parameters"]

CONTROLLER_NODE = "robotino_controller"  # the controller node's name (each robot's, in its namespace)
_VALUE_FIELDS = {1: "bool_value", 2: "integer_value", 3: "double_value", 4: "string_value"}  # rcl_interfaces types

_PLAN_TYPES = {"wheel_voltage_plan": "trajectory_msgs/msg/JointTrajectory",
               "cmd_vel_plan": "trajectory_msgs/msg/MultiDOFJointTrajectory"}
TRACKING_KEY = "error_x_m"  # the controller's tracking status is the diagnostics status with this key
# the controller's tracking status from a DiagnosticArray's bytes (`ros.cdr.diagnostics_with`) or its message
read_controller_diagnostics = diagnostics_with(TRACKING_KEY)
controller_diagnostics_of_message = diagnostics_with_of_message(TRACKING_KEY)


@overload
def find_topic(bag: BagReader, suffix: str, type_name: str, required: Literal[True] = True) -> str: ...


@overload
def find_topic(bag: BagReader, suffix: str, type_name: str, required: bool) -> str | None: ...


def find_topic(bag: BagReader, suffix: str, type_name: str, required: bool = True) -> str | None:
    """The recorded topic named ``/<suffix>`` (or ``/<ns>/<suffix>``) of type `type_name`.

    Raises
    ------
    BagError
        If `required` and there is no such topic, or there are several.
    """
    names = [
        n for n, t in bag.topics.items() if (n == "/" + suffix or n.endswith("/" + suffix)) and t.type == type_name
    ]
    # the shallowest wins: /robot1/odom, not /robot1/ground_truth/odom; two robots' odom stay ambiguous
    depth = min((n.count("/") for n in names), default=0)
    names = [n for n in names if n.count("/") == depth]
    if len(names) == 1:
        return names[0]
    if len(names) > 1:
        raise BagError(f"{bag.path}: several {suffix} topics ({', '.join(names)})")
    if required:
        raise BagError(f"{bag.path}: no '{suffix}' topic of type {type_name} in the recording")
    return None


def plan_topic(bag: BagReader) -> tuple[str, str] | None:
    """(topic, interface) of the plans in a recording, None without plans."""
    for name, interface in (("wheel_voltage_plan", "voltages"), ("cmd_vel_plan", "cmd_vel")):
        topic = find_topic(bag, name, _PLAN_TYPES[name], False)
        if topic is not None:
            return topic, interface
    return None


def converted_by_publish_time(bag: BagReader, topic: str | None,
                              convert: Callable[[BagMessage], Any]) -> list[tuple[int, Any]]:
    """(publish time [ns], `convert(message)`) of a topic, in publish-time order ([] for None); BagError if a
    message does not decode.
    """
    if topic is None:
        return []
    items = []
    for m in bag.messages([topic]):
        try:
            items.append((m.publish_time_ns, convert(m)))
        except Exception as exc:  # SerdeError, struct.error, IndexError, KeyError (unknown type)
            raise BagError(f"{bag.path}: a {m.type} message on {topic} does not decode: {exc!r}") from None
    items.sort(key=lambda item: item[0])
    return items


def by_publish_time(bag: BagReader, topic: str | None) -> list[tuple[int, Any]]:
    """(publish time [ns], deserialised message) of a topic, in publish-time order ([] for None).

    rosbags' CDR decoder (its ROS 2 Jazzy types) builds the messages: 2-3 times faster than rclpy's
    `deserialize_message` and without importing rclpy.

    Raises
    ------
    BagError
        If a message of `topic` does not decode as its type.
    """
    store = _typestore()
    return converted_by_publish_time(bag, topic, lambda m: store.deserialize_cdr(m.data, m.type))


def controller_diagnostics(msg: Any) -> dict[str, str] | None:
    """Key-values of the controller's tracking status in a DiagnosticArray (None if it has none)."""
    return controller_diagnostics_of_message(msg)[1]


def run_parameters(bag: BagReader) -> tuple[dict[str, Any] | None, str]:
    """The run's parameters (flat dotted names: the robot's, the control's, the chain's) and scenario stored by
    the recorder, if any.
    """
    record = bag.metadata.get(RUN_METADATA)
    if record is None:
        prefix = RUN_METADATA + "."
        record = {k[len(prefix):]: v for k, v in bag.custom_data.items() if k.startswith(prefix)}
    scenario = record.get("scenario", "") or ""
    text = record.get("parameters")
    if not text:
        return None, scenario
    try:
        values = json.loads(text)
    except json.JSONDecodeError:
        raise BagError(f"{bag.path}: the stored run parameters are not valid JSON") from None
    return (values or None), scenario


def controller_parameters(bag: BagReader, node: str | None = None) -> dict[str, Any]:
    """The parameter values the controller's parameter events in the recording give (declared, then changed, in
    publish order): of the node named `node` (its full name, e.g. ``/robot1/robotino_controller``), or of any node
    named `CONTROLLER_NODE`; {} without events. Decoded by rclpy: rosbags refuses some events (their CDR size).
    """
    from rclpy.serialization import deserialize_message
    from rcl_interfaces.msg import ParameterEvent

    topic = find_topic(bag, "parameter_events", "rcl_interfaces/msg/ParameterEvent", False)
    values: dict[str, Any] = {}
    for m in sorted(bag.messages([topic] if topic else []), key=lambda m: m.publish_time_ns):
        try:
            event = deserialize_message(m.data, ParameterEvent)
        except Exception as exc:  # rclpy's deserialization error of a damaged message
            raise BagError(f"{bag.path}: a {m.type} message on {topic} does not decode: {exc!r}") from None
        if event.node == node if node is not None else event.node.rsplit("/", 1)[-1] == CONTROLLER_NODE:
            for parameter in (*event.new_parameters, *event.changed_parameters):
                kind = _VALUE_FIELDS.get(parameter.value.type)
                if kind is not None:
                    values[parameter.name] = getattr(parameter.value, kind)
    return values
