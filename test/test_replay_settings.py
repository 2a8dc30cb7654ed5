"""The replays take the controller loop's settings the node ran with (`recording.replay_inputs.loop_settings`).

A realtime fleet's controllers run with ``reference_timeout_s`` 0.2 s (their trajectory nodes send a preview every
10 periods, `system.processes.fleet_realtime_parameters`), not the loop's default 0.1 s. A replay with the default
takes a tick more than 0.1 s after the last preview's arrival for a stale reference (no answer) where the node
stepped, and every answer after it differs (the next step interval): `regress` failed on realtime fleet bags.

Here a `ControllerLoop` with the fleet's settings plays the node on a scripted realtime run whose previews (N + 10
points, one every 10 periods) come 1 ms after their stamp but one 30 ms late, so that three ticks are answered from
a preview 103-123 ms old; its inputs and outputs are written as the node and a recorder would have (`BagWriter`),
with the run parameters the recorder stores. The truth is the node's own answers: `regress_bag` reproduces every
one (deviation 0) from the stored settings, and not without them. `run`/the launch give the recorder the settings
they give the controllers (`system.processes.node_arguments`); the controller's parameter events, when recorded,
take precedence.
"""

from __future__ import annotations

import json
import math

import pytest
from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray

from robotino_geom_mpc.loop.controller_loop import ControllerLoop, LoopSettings
from robotino_geom_mpc.loop.events import Command, Diagnostic, Now
from robotino_geom_mpc.params.files import load_params, read_parameter_file
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.params.specs import ALL_SPECS, RECORDED_CONTROLLER_SPECS
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bag_writer import BagWriter
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.recording.replay_inputs import loop_settings
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.ros.controller_cdr import diagnostics_cdr
from robotino_geom_mpc.ros.decode import odometry_input, preview_input
from robotino_geom_mpc.ros.messages import ns_to_stamp, odometry_message, preview_message
from robotino_geom_mpc.system.processes import fleet_arguments, node_arguments

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params()
MS = 1_000_000
START = 1_000 * MS
EVERY = 10  # a preview every this many control periods, with the points to cover them
FLEET = LoopSettings(reference_timeout_s=0.2)
REF = make_reference("paper-circle")
TOPICS = {"/odom": "nav_msgs/msg/Odometry", "/reference_preview": "trajectory_msgs/msg/MultiDOFJointTrajectory",
          "/wheel_voltages": "std_msgs/msg/Float64MultiArray", "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
          "/parameter_events": "rcl_interfaces/msg/ParameterEvent"}


def _odometry(stamp: int):
    """The robot on the reference, 1 mm off in x."""
    msg = odometry_message()
    msg.header.stamp = ns_to_stamp(stamp)
    x, y, theta = REF.position((stamp - START) * 1e-9)
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, q.z, q.w = x + 1e-3, y, math.sin(theta / 2), math.cos(theta / 2)
    return msg


def _run() -> tuple[list[tuple[int, str, bytes]], int]:
    """(publish time, topic, message) of what the node's inputs and outputs were, in publish order; the number of
    ticks the node answered from a preview more than 0.1 s old.
    """
    loop = ControllerLoop(ROBOT, CONTROL, Now(START, START), FLEET)
    sent: list[tuple[int, str, bytes]] = []
    events = []  # (the node's clock at the input, kind, stamp)
    for j in range(12):
        stamp = START + j * EVERY * 10 * MS
        events.append((stamp + (30 if j == 5 else 1) * MS, 0, stamp))  # the sixth preview 30 ms late
    events += [(START + 3 * MS + k * 10 * MS + MS, 1, START + 3 * MS + k * 10 * MS) for k in range(115)]
    received, old = 0, 0
    for clock, kind, stamp in sorted(events):
        if kind == 0:
            msg = preview_message(REF, stamp - START, CONTROL.period_s, CONTROL.horizon + EVERY - 1)
            msg.header.stamp = ns_to_stamp(stamp)
            sent.append((clock - MS // 2, "/reference_preview", serialize_message(msg)))
            outputs = loop.on_input(preview_input(msg), Now(clock, clock))
            received = clock
        else:
            msg = _odometry(stamp)
            sent.append((stamp + MS // 2, "/odom", serialize_message(msg)))
            outputs = loop.on_input(odometry_input(msg), Now(clock, clock))
            old += any(isinstance(o, Command) for o in outputs) and clock - received > 100 * MS
        sent += node_messages(clock, outputs)
    return sent, old


def node_messages(clock: int, outputs: list) -> list[tuple[int, str, bytes]]:
    """(publish time, topic, message) of what the node publishes for a loop's `outputs` at `clock`: a command, then
    its status.
    """
    messages = []
    for j, out in enumerate(outputs):
        if isinstance(out, Command):
            messages.append((clock + (j + 1) * 10_000, "/wheel_voltages",
                             serialize_message(Float64MultiArray(data=list(out.values)))))
        elif isinstance(out, Diagnostic):
            messages.append((clock + (j + 1) * 10_000, "/diagnostics", diagnostics_cdr(
                out.stamp_ns, bytes((int(out.level),)), out.message, [k.encode() for k in out.keys], out.values)))
    return messages


def _record(path, sent, stored: dict | None, events: list[tuple[str, float]] = ()) -> None:
    """`sent` as a recorder that stored the run parameters `stored`, with the parameter events of `events`
    (node's full name, ``reference_timeout_s``) before it.
    """
    with BagWriter(path, compression="none") as writer:
        if stored is not None:
            writer.store_run_metadata({"scenario": "paper-circle", "parameters": json.dumps(stored)})
        channels = {topic: writer.add_topic(topic, kind) for topic, kind in TOPICS.items()}
        for k, (node, value) in enumerate(events):
            value_msg = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
            event = ParameterEvent(node=node, new_parameters=[Parameter(name="reference_timeout_s", value=value_msg)])
            writer.write(channels["/parameter_events"], START - MS + k, serialize_message(event), START - MS + k)
        for publish, topic, data in sorted(sent, key=lambda item: item[0]):
            writer.write(channels[topic], publish + 100_000, data, publish)


def _run_parameters() -> dict:
    return {k: v for k, v in read_parameter_file(default_params_file()).items() if k in {s.name for s in ALL_SPECS}}


def test_regress_replays_a_realtime_fleet_controller_with_the_settings_the_recorder_stored(tmp_path):
    sent, old = _run()
    assert old == 3  # ticks answered from a preview 103, 113 and 123 ms old: stale under the default 0.1 s
    _record(tmp_path / "stored", sent, {**_run_parameters(), "reference_timeout_s": FLEET.reference_timeout_s})
    result = regress_bag(tmp_path / "stored")
    answered = sum(1 for _, topic, _ in sent if topic == "/wheel_voltages")
    assert result.compared == result.ticks == answered > 100 and result.max_deviation_v == 0.0, result
    _record(tmp_path / "bare", sent, _run_parameters())  # the loop's default timeout: not the node's run
    result = regress_bag(tmp_path / "bare")
    assert not result.passed and result.ticks == answered - old and result.max_deviation_v > 1e-6, result


def test_the_controllers_parameter_events_take_precedence_over_the_stored_settings(tmp_path):
    """Of the controller in the odometry's namespace only (a fleet's recording holds every robot's)."""
    sent = [(START, "/odom", serialize_message(_odometry(START)))]
    stored = {**_run_parameters(), "reference_timeout_s": 0.3, "odom_timeout_s": 0.25}
    _record(tmp_path / "bag", sent, stored, [("/robot2/robotino_controller", 0.7), ("/robotino_controller", 0.4)])
    assert loop_settings(BagReader(tmp_path / "bag"), "/odom") == LoopSettings(odom_timeout_s=0.25,
                                                                               reference_timeout_s=0.4)
    _record(tmp_path / "other", sent, stored, [("/robot2/robotino_controller", 0.7)])
    assert loop_settings(BagReader(tmp_path / "other"), "/odom").reference_timeout_s == 0.3
    _record(tmp_path / "none", sent, None)
    assert loop_settings(BagReader(tmp_path / "none"), "/odom") == LoopSettings()
    _record(tmp_path / "bad", sent, {**stored, "odom_timeout_s": "soon"})  # a recorder given a string: said so
    with pytest.raises(BagError, match="loop settings in the recording are not numbers"):
        loop_settings(BagReader(tmp_path / "bad"), "/odom")


def test_run_and_the_fleet_give_the_recorder_the_controllers_loop_settings():
    """`node_arguments` gives the recorder the loop settings and the chain it gives the controller (the realtime
    fleet's timeout included), and only those (`params.specs.RECORDED_CONTROLLER_SPECS`).
    """
    def recorder(args: list[str]) -> dict[str, str]:
        return dict(a.split(":=", 1) for a in args if ":=" in a and a.split(":=", 1)[0] in
                    {s.name for s in RECORDED_CONTROLLER_SPECS})

    params = default_params_file()
    single = node_arguments("paper-circle", params, 2.0, False, bag="b",
                            overrides={"controller_node": {"odom_timeout_s": 0.3, "start_enabled": False}})
    assert recorder(single["recorder_node"]) == {"odom_timeout_s": "0.3"}
    fleet = fleet_arguments("paper-circle", params, 2.0, False, 3, bag="b")
    timeout = round(LoopSettings().reference_timeout_s + 10 * CONTROL.period_s, 9)
    assert recorder(fleet["recorder_node"]) == {"reference_timeout_s": repr(timeout)}
    assert recorder(node_arguments("paper-circle", params, 2.0, True, bag="b")["recorder_node"]) == {}
    chain = node_arguments("paper-circle", params, 2.0, False, bag="b", overrides={"controller_node": {
        "chain.active": "enabled", "chain.driver_phase_s": 0.012}})  # `run --chain`'s
    assert recorder(chain["recorder_node"]) == {"chain.active": "enabled", "chain.driver_phase_s": "0.012"}
