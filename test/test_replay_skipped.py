"""The replays skip the realtime odometry the controller never took (`recording.replay_inputs.NodeClock.took`).

The realtime controller reads ``odom`` keep-last 1 (`ros.qos.LATEST_QOS`): while it is busy, a newer odometry
replaces an older one in its reader, so the older is never taken, never answered and has no status, though a
recorder (its own reader) has it. A replay that answered it would step the loop once more than the node did, and
every later answer would differ (the step interval, the MPCs' previous input).

Here a `ControllerLoop` with a realtime fleet's settings plays the node on a scripted run (`test_replay_settings`:
a preview every 10 periods) in which six odometries are replaced before the node takes them; every odometry is
recorded, with the node's answers and statuses. The truth is the node's own answers: `regress_bag` reproduces
every one (deviation 0), and not when it answers the replaced ones too.
"""

from __future__ import annotations

import pytest
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray

from robotino_geom_mpc.loop.controller_loop import ControllerLoop
from robotino_geom_mpc.loop.events import Command, Diagnostic, Now
from robotino_geom_mpc.recording import replay_inputs
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.ros.controller_cdr import diagnostics_cdr
from robotino_geom_mpc.ros.decode import odometry_input, preview_input
from robotino_geom_mpc.ros.messages import ns_to_stamp, preview_message
from test_replay_settings import CONTROL, EVERY, FLEET, MS, REF, ROBOT, START, _odometry, _record, _run_parameters

pytestmark = pytest.mark.unit

REPLACED = {40, 80, 81, 82, 120, 121}  # odometries a newer one replaced in the node's reader


def _run() -> list[tuple[int, str, bytes]]:
    """(publish time, topic, message) of the node's inputs (every odometry) and outputs (of those it took)."""
    loop = ControllerLoop(ROBOT, CONTROL, Now(START, START), FLEET)
    sent: list[tuple[int, str, bytes]] = []
    events = [(START + j * EVERY * 10 * MS + MS, 0, START + j * EVERY * 10 * MS) for j in range(16)]
    events += [(START + 3 * MS + k * 10 * MS + MS, 1, k) for k in range(150)]
    for clock, kind, index in sorted(events):
        if kind == 0:
            msg = preview_message(REF, index - START, CONTROL.period_s, CONTROL.horizon + EVERY - 1)
            msg.header.stamp = ns_to_stamp(index)
            sent.append((clock - MS // 2, "/reference_preview", serialize_message(msg)))
            outputs = loop.on_input(preview_input(msg), Now(clock, clock))
        else:
            stamp = START + 3 * MS + index * 10 * MS
            msg = _odometry(stamp)
            sent.append((stamp + MS // 2, "/odom", serialize_message(msg)))
            if index in REPLACED:
                continue
            outputs = loop.on_input(odometry_input(msg), Now(clock, clock))
        for j, out in enumerate(outputs):  # the node publishes a command, then its status
            if isinstance(out, Command):
                sent.append((clock + (j + 1) * 10_000, "/wheel_voltages",
                             serialize_message(Float64MultiArray(data=list(out.values)))))
            elif isinstance(out, Diagnostic):
                sent.append((clock + (j + 1) * 10_000, "/diagnostics", diagnostics_cdr(
                    out.stamp_ns, bytes((int(out.level),)), out.message, [k.encode() for k in out.keys],
                    out.values)))
    return sent



def test_regress_skips_the_odometry_the_node_never_took(tmp_path, monkeypatch):
    sent = _run()
    _record(tmp_path / "bag", sent, {**_run_parameters(), "reference_timeout_s": FLEET.reference_timeout_s})
    answered = sum(1 for _, topic, _ in sent if topic == "/wheel_voltages")
    assert sum(1 for _, topic, _ in sent if topic == "/odom") == answered + len(REPLACED)
    result = regress_bag(tmp_path / "bag")
    assert result.compared == result.ticks == answered > 100 and result.max_deviation_v == 0.0, result
    # answering the replaced odometries too (as the replays did): one step more each, the answers after differ
    monkeypatch.setattr(replay_inputs.NodeClock, "took", lambda self, stamp: True)
    result = regress_bag(tmp_path / "bag")
    assert not result.passed and result.ticks == answered + len(REPLACED) and result.max_deviation_v > 1e-6, result
