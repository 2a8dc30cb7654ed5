"""The exact replay of a chain recording (`recording.regress_chain`) that begins on ``cmd_vel`` before ``odom``.

The recorder subscribes topic by topic, so a recording may hold the controller's answers to odometries it lacks (its
``cmd_vel`` subscription came first): the bring-up page's run of a controller started disabled, enabled later with
the reference starting at the enable, failed its replay that way (every answer compared with the one recorded
three before it). Here a `ControllerLoop` in chain mode plays the node on a scripted run -- held previews and zero
answers while disabled, the enable, the reference starting at it, the robot moving as commanded one driver pass
later -- and its inputs and outputs are written as the node and a late recorder would have (`BagWriter`: the
commands from the start, the odometry, previews and statuses from a later time). The truth is the node's own answers:
`regress_bag` must reproduce every answer to a recorded odometry (deviation 0) whatever the recorder missed.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from geometry_msgs.msg import Twist
from rclpy.serialization import deserialize_message, serialize_message

from robotino_geom_mpc.loop.controller_loop import ControllerLoop
from robotino_geom_mpc.loop.events import Command, Diagnostic, Now, Zero
from robotino_geom_mpc.model.driver_chain import ChainParams, chain_params
from robotino_geom_mpc.params.files import load_params, read_parameter_file
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.params.specs import ALL_SPECS
from robotino_geom_mpc.recording.bag_writer import BagWriter
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.ros.controller_cdr import diagnostics_cdr
from robotino_geom_mpc.ros.decode import odometry_input, preview_input
from robotino_geom_mpc.ros.messages import ns_to_stamp, odometry_message, preview_message

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params()
MS = 1_000_000
START = 1_000 * MS  # the node's clock at the first input
PASS_NS = round(1e9 / 30)  # the driver's passes (its odometry stamps)
ENABLE = START + 401 * MS
END = ENABLE + 1_500 * MS
REF = make_reference("paper-circle")
TOPICS = {"/cmd_vel": "geometry_msgs/msg/Twist", "/odom": "nav_msgs/msg/Odometry",
          "/reference_preview": "trajectory_msgs/msg/MultiDOFJointTrajectory",
          "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}


def _preview(clock: int):
    """The trajectory node's preview at `clock`: the reference's start at rest until the enable, then the reference
    from t = 0 at the enable.
    """
    msg = preview_message(REF, max(clock - ENABLE, 0), CONTROL.period_s, CONTROL.horizon)
    msg.header.stamp = ns_to_stamp(clock)
    if clock < ENABLE:
        start = msg.points[0].transforms[0]
        for point in msg.points:
            point.transforms[0] = start
            point.velocities[0], point.accelerations[0] = Twist(), Twist()
    return msg


def _odometry(stamp: int, pose: np.ndarray, twist: np.ndarray):
    msg = odometry_message()
    msg.header.stamp = ns_to_stamp(stamp)
    p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    p.x, p.y, q.z, q.w = pose[0], pose[1], math.sin(pose[2] / 2), math.cos(pose[2] / 2)
    v.linear.x, v.linear.y, v.angular.z = twist.tolist()
    return msg


def _run(chain: ChainParams | None = None) -> list[tuple[int, str, bytes]]:
    """(publish time, topic, message) of everything the scripted run sends, in publish order (the controller's
    chain `chain`, default the preset).
    """
    loop = ControllerLoop(ROBOT, CONTROL, Now(START, START), interface="cmd_vel", chain=chain or chain_params(),
                          enabled=False)
    sent: list[tuple[int, str, bytes]] = []
    pose = REF.position(0.0).copy()
    acting = np.zeros(3)  # the twist the robot follows (base_link): the one answered a pass before
    latest = np.zeros(3)
    events = [(t, 0) for t in range(START, END, 10 * MS)]  # previews every control period
    events += [(START + 3 * MS + k * PASS_NS, 1) for k in range((END - START) // PASS_NS)]  # driver passes
    events.append((ENABLE, 2))
    for clock, kind in sorted(events):
        if kind == 0:
            msg = _preview(clock)
            sent.append((clock, "/reference_preview", serialize_message(msg)))
            outputs = loop.on_input(preview_input(msg), Now(clock + MS // 2, clock + MS // 2))
        elif kind == 2:
            outputs = loop.on_enable(True, Now(clock, clock))
        else:
            c, s = math.cos(pose[2]), math.sin(pose[2])
            world = np.array([c * acting[0] - s * acting[1], s * acting[0] + c * acting[1], acting[2]])
            pose = pose + world * PASS_NS * 1e-9
            acting = latest
            outputs = []
            for sample in range(1 + (clock // PASS_NS) % 2):  # every other pass two samples of its stamp
                msg = _odometry(clock, pose, world)
                sent.append((clock + MS + sample * MS // 2, "/odom", serialize_message(msg)))
                now = clock + 2 * MS + sample * MS
                outputs += [(now, out) for out in loop.on_input(odometry_input(msg), Now(now, now))]
            _send(sent, outputs)
            latest = next((np.array(out.values) for _, out in reversed(outputs) if isinstance(out, Command)),
                          latest)
            continue
        _send(sent, [(clock + MS // 2, out) for out in outputs])
    return sent


def _send(sent: list[tuple[int, str, bytes]], outputs: list) -> None:
    """The node's publishing of a callback's outputs, in their order (a command, then its status)."""
    for j, (now, out) in enumerate(outputs):
        publish = now + 10_000 * (j + 1)
        if isinstance(out, (Command, Zero)):
            twist = Twist()
            twist.linear.x, twist.linear.y, twist.angular.z = out.values if isinstance(out, Command) else (0, 0, 0)
            sent.append((publish, "/cmd_vel", serialize_message(twist)))
        elif isinstance(out, Diagnostic):
            sent.append((publish, "/diagnostics", diagnostics_cdr(
                out.stamp_ns, bytes((int(out.level),)), out.message, [k.encode() for k in out.keys], out.values)))


def _record(path, sent: list[tuple[int, str, bytes]], late: dict[str, int], stored: dict | None = None) -> int:
    """Write `sent` as a recorder whose subscription to a topic of `late` began at that time (and that stored the
    run parameters `stored`); returns the commands written for odometries the recording lacks.
    """
    first_odom = min((p for p, topic, _ in sent if topic == "/odom" and p >= late["/odom"]), default=0)
    with BagWriter(path, compression="none") as writer:
        if stored is not None:
            writer.store_run_metadata({"scenario": "", "parameters": json.dumps(stored)})
        channels = {topic: writer.add_topic(topic, kind) for topic, kind in TOPICS.items()}
        for publish, topic, data in sorted(sent, key=lambda item: item[0]):
            if publish >= late.get(topic, 0):
                writer.write(channels[topic], publish + 100_000, data, publish)
    return sum(1 for p, topic, _ in sent if topic == "/cmd_vel" and p < first_odom)


@pytest.mark.parametrize("late_ms", [0, 35, 50])
def test_replay_of_a_recording_begun_on_cmd_vel_before_odom(tmp_path, late_ms):
    sent = _run()
    speeds = {round(deserialize_message(data, Twist).linear.x, 6) for _, topic, data in sent if topic == "/cmd_vel"}
    assert len(speeds) > 20  # the run tracked: the answers after the enable differ from one to the next
    late = START + late_ms * MS
    extra = _record(tmp_path / "bag", sent, {"/odom": late, "/diagnostics": late + MS, "/reference_preview": late})
    assert (extra > 0) == (late_ms > 0), extra  # the recording holds answers to odometries it lacks
    result = regress_bag(tmp_path / "bag")
    answers = sum(1 for p, topic, _ in sent if topic == "/odom" and p >= late)
    assert result.chain_source is not None and result.compared == result.ticks == answers
    assert result.max_deviation_v == 0.0 and result.passed, result


def test_replay_takes_the_chain_the_recorder_stored(tmp_path):
    """A controller on an identified chain (not the preset's ramps, timeout or round trip): the recorder stores its
    ``chain.*`` with the run parameters (as the launch and `run` give them to it), and `regress_bag` replays with
    them and no parameter file; the same recording without them replays with the preset and does not match.
    """
    identified = chain_params({"chain.ramp_translation_m_s2": 0.7, "chain.ramp_rotation_rad_s2": 2.0,
                               "chain.speed_loop_time_constant_s": 0.04, "chain.driver_phase_s": 0.012})
    sent = _run(identified)
    run = {k: v for k, v in read_parameter_file(default_params_file()).items() if k in {s.name for s in ALL_SPECS}}
    for name, stored in (("stored", {**run, **identified.values(), "chain.active": "enabled"}), ("bare", None)):
        _record(tmp_path / name, sent, {"/odom": 0}, stored)
        result = regress_bag(tmp_path / name)
        if stored is not None:
            assert result.chain_source == "the run parameters the recorder stored"
            assert result.max_deviation_v == 0.0 and result.passed and result.compared == result.ticks > 80, result
        else:
            assert result.chain_source.startswith("the robocup-logistics preset")
            assert not result.passed and result.max_deviation_v > 1e-3, result
