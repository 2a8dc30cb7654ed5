"""``report`` and ``regress`` on a recording through the driver chain, with and without the simulator's truth.

A ``run --realtime --command-interface cmd_vel --chain robocup-logistics`` of paper-circle is recorded; a copy of its
bag without ``ground_truth/odom``, ``wheel_currents``, ``applied_voltages`` and ``joint_states`` (what a real robot's
recording lacks), rewritten by the mcap library (a writer independent of the package's), stands for a real robot's.
The report of the copy says it measured against odometry and its RMS error equals one computed here from the
original bag read by rosbags (odom against the reference preview); ``regress`` replays both to 1e-12 and fails on
a copy whose one twist was changed by 1e-6.
"""

from __future__ import annotations

import bisect
import json
import math
import subprocess
import sys

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from rosbags.highlevel import AnyReader

from regress_helpers import regress_verb
from robotino_geom_mpc.cli import main
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.recording.report import by_publish_time

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DURATION_S = 8.0
SETTLE_S = 1.0
REAL_ROBOT_LACKS = {"/ground_truth/odom", "/wheel_currents", "/applied_voltages", "/joint_states"}


@pytest.fixture(scope="module")
def chain_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("chain")
    done = subprocess.run([sys.executable, "-m", "robotino_geom_mpc", "run", "--scenario", "paper-circle", "--realtime",
                           "--command-interface", "cmd_vel", "--chain", "robocup-logistics", "--duration",
                           str(DURATION_S), "--out", str(out), "--no-plots"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    return out


def _rewrite(source, target, drop=frozenset(), change=None) -> None:
    """Copy an MCAP with the mcap library, leaving out the topics `drop`; `change(topic, index, data)` may replace
    a message's bytes (index: its place on its topic).
    """
    seen: dict[str, int] = {}
    with open(source, "rb") as inp, open(target, "wb") as out:
        reader, writer = make_reader(inp), Writer(out)
        writer.start()
        summary = reader.get_summary()
        schemas, channels = {}, {}
        for cid, channel in summary.channels.items():
            if channel.topic in drop:
                continue
            schema = summary.schemas[channel.schema_id]
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            channels[cid] = writer.register_channel(channel.topic, channel.message_encoding, schemas[schema.id],
                                                    channel.metadata)
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        for _, channel, message in reader.iter_messages(log_time_order=True):
            if channel.id not in channels:
                continue
            index = seen[channel.topic] = seen.get(channel.topic, -1) + 1
            data = message.data if change is None else change(channel.topic, index, message.data)
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time, message.sequence)
        writer.finish()


@pytest.fixture(scope="module")
def real_like(chain_run, tmp_path_factory):
    """The recording without what a real robot's lacks (a bare .mcap)."""
    copy = tmp_path_factory.mktemp("real") / "real_like.mcap"
    _rewrite(next((chain_run / "bag").glob("*.mcap")), copy, REAL_ROBOT_LACKS)
    return copy


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _odometry_rms(bag_dir, span_s: float) -> tuple[float, int]:
    """(RMS x-y error after SETTLE_S, ticks) straight from the bag by rosbags: per odom stamp its last message,
    against the newest preview stamped at or before it (within `span_s`), point 0 moved by v dt + a dt^2 / 2;
    a stamp with no such preview against the last ``reference_path``, linear between its poses' stamps (none
    outside them).
    """
    odom: dict[int, tuple[float, float]] = {}
    previews: dict[int, np.ndarray] = {}
    path: list[tuple[int, float, float]] = []
    with AnyReader([bag_dir]) as reader:
        wanted = [c for c in reader.connections if c.topic in ("/odom", "/reference_preview", "/reference_path")]
        for connection, _, raw in reader.messages(wanted):
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if connection.topic == "/reference_path":
                path = [(p.header.stamp.sec * 1_000_000_000 + p.header.stamp.nanosec, p.pose.position.x,
                         p.pose.position.y) for p in msg.poses]
            elif connection.topic == "/odom":
                odom[stamp] = (msg.pose.pose.position.x, msg.pose.pose.position.y)  # the last of its stamp
            elif stamp not in previews:
                point = msg.points[0]
                tf, v, a = point.transforms[0], point.velocities[0], point.accelerations[0]
                previews[stamp] = np.array([[tf.translation.x, tf.translation.y], [v.linear.x, v.linear.y],
                                            [a.linear.x, a.linear.y]])
    preview_stamps = sorted(previews)
    rows = []
    path_t = np.array([t for t, _, _ in path], dtype=np.int64)
    for stamp in sorted(odom):
        i = bisect.bisect_right(preview_stamps, stamp) - 1
        if i < 0 or stamp - preview_stamps[i] > span_s * 1e9:
            if not path or not path_t[0] <= stamp <= path_t[-1]:
                continue
            reference = np.array([np.interp(stamp, path_t, [q[j] for q in path]) for j in (1, 2)])
        else:
            p, v, a = previews[preview_stamps[i]]
            dt = (stamp - preview_stamps[i]) * 1e-9
            reference = p + v * dt + 0.5 * a * dt * dt
        rows.append((stamp, np.hypot(*(np.array(odom[stamp]) - reference))))
    t0 = rows[0][0]
    after = np.array([e for s, e in rows if (s - t0) * 1e-9 >= SETTLE_S - 1e-12])
    return float(np.sqrt(np.mean(after**2))), len(rows)


def test_report_with_ground_truth_says_so(chain_run):
    metrics = json.loads((chain_run / "metrics.json").read_text())
    assert metrics["truth"] == "ground_truth" and "timing" not in metrics and metrics["peak_current_a"] > 0


def test_report_without_ground_truth_uses_odometry_and_says_so(chain_run, real_like, capsys):
    assert main(["report", str(real_like)]) == 0
    out = capsys.readouterr().out
    folder = real_like.parent / "real_like-report"
    assert "truth: odometry" in out and f"wrote {folder / 'metrics.json'}" in out
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["truth"] == "odometry"
    # the figures of Figs. 4-6 from odometry and the commands: no currents, no voltages through the driver
    assert sorted(p.name for p in folder.glob("*.png")) == ["commands.png", "errors.png", "theta.png", "xy_path.png"]
    assert metrics["peak_current_a"] is None and metrics["peak_voltage_v"] is None
    horizon, period = metrics["horizon"], metrics["control_period_s"]
    rms, ticks = _odometry_rms(chain_run / "bag", horizon * period)
    assert metrics["samples"] == ticks
    assert metrics["rms_position_error_m"] == pytest.approx(rms, rel=1e-9, abs=1e-12)
    # the chain's timing: the driver's 30 Hz passes, one or two odometry samples a stamp
    timing = metrics["timing"]
    assert timing["stamp_rate_hz"] == pytest.approx(30.0, rel=1e-3)
    assert set(timing["samples_per_stamp"]) <= {"1", "2"} and timing["samples_per_stamp"]["2"] > 0
    assert timing["stamps_out_of_order"] == 0 and timing["first_response_ms"] > 0


@pytest.mark.parametrize("which", ["recorded", "real_like"])
def test_regress_replays_the_chain(chain_run, real_like, which, capsys, monkeypatch):
    bag = chain_run / "bag" if which == "recorded" else real_like
    status, result = regress_verb(bag, monkeypatch)
    with AnyReader([chain_run / "bag"]) as reader:
        twists = sum(1 for c in reader.connections if c.topic == "/cmd_vel" for _ in reader.messages([c]))
    # the chain's parameters: the controller's, where the recorder caught its /parameter_events, else the preset
    # (the same here: run --chain robocup-logistics)
    assert result.command == "cmd_vel" and result.chain_source is not None
    # each recorded twist but the stop's zero is an answer compared
    assert twists - 2 <= result.compared <= twists and result.max_deviation_v <= 1e-12 and result.passed
    assert status == 0
    assert capsys.readouterr().out.startswith(f"PASS: {result.compared} of {result.ticks} ticks compared")


def test_regress_fails_on_a_changed_twist(chain_run, tmp_path, capsys, monkeypatch):
    from rclpy.serialization import deserialize_message, serialize_message
    from geometry_msgs.msg import Twist

    source = next((chain_run / "bag").glob("*.mcap"))
    with AnyReader([chain_run / "bag"]) as reader:
        twists = [reader.deserialize(raw, c.msgtype) for c in reader.connections if c.topic == "/cmd_vel"
                  for _, _, raw in reader.messages([c])]
    target = next(i for i in range(len(twists) // 2, len(twists)) if twists[i].linear.x != 0.0)

    def change(topic: str, index: int, data: bytes) -> bytes:
        if topic != "/cmd_vel" or index != target:
            return data
        msg = deserialize_message(data, Twist)
        msg.linear.x += 1e-6
        return serialize_message(msg)

    _rewrite(source, tmp_path / "changed.mcap", change=change)
    status, result = regress_verb(tmp_path / "changed.mcap", monkeypatch)
    assert not result.passed and 0.5e-6 < result.max_deviation_v < 2e-6
    assert status == 1
    assert capsys.readouterr().out.startswith("FAIL")


def test_regress_replays_a_chain_run_started_disabled(tmp_path):
    """``start_enabled`` false: the node holds (a zero twist and the status ``disabled`` per odometry, no step)
    until ``~/enable`` true; the replay holds where the status says so and reproduces every twist after.
    """
    import signal
    import time

    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import SetBool

    from harness import Harness
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import NodeGroup, node_arguments

    chain = {"command_interface": "cmd_vel", "chain.active": "enabled"}
    bag = tmp_path / "bag"
    args = node_arguments("paper-circle", default_params_file(), 0.0, False, bag=bag, command_interface="cmd_vel",
                          overrides={"plant_node": {**chain, "wheel_pi.rate_hz": 200.0},
                                     "controller_node": {**chain, "start_enabled": False}})
    with Harness("chain_disabled_recording") as h, NodeGroup(log_dir=tmp_path) as group:
        nodes = {name: group.start(name, argv) for name, argv in args.items()}
        statuses = h.collect("/diagnostics", DiagnosticArray)
        client = h.node.create_client(SetBool, "/robotino_controller/enable")
        assert client.wait_for_service(timeout_sec=60.0)
        # held for 1 s of odometry (30 Hz) as this process sees it: a loaded host starts the plant later
        assert h.spin_until(lambda: sum(any(s.message == "disabled" for s in m.status) for m in statuses) >= 30, 60.0)
        assert h._call(client, SetBool.Request(data=True), 30.0).message == "enabled"
        h.spin_for(4.0)
        for name in ("trajectory_node", "controller_node", "plant_node", "robot_description_publisher"):
            if name in nodes:
                nodes[name].popen.send_signal(signal.SIGINT)
        time.sleep(1.0)
        nodes["recorder_node"].popen.send_signal(signal.SIGINT)
        assert nodes["recorder_node"].popen.wait(30) == 0
    result = regress_bag(bag)
    held = sum(1 for _, msg in by_publish_time(BagReader(bag), "/diagnostics")
               if any(s.message == "disabled" for s in msg.status))
    print(f"{held} odometries held, then {result.compared} of {result.ticks} compared, max deviation "
          f"{result.max_deviation_v:.1e}")
    assert held > 20 and result.compared > 60  # 2 s held, 4 s tracked at 30 Hz
    assert result.max_deviation_v <= 1e-12 and result.passed, result
