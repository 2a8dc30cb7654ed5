"""The replays of a realtime controller that fell behind: the odometry it never took, the previews it took late.

* The realtime controller reads ``odom`` keep-last 1 (`ros.qos.LATEST_QOS`): while it is busy, a newer odometry
  replaces an older one in its reader, so the older is never taken, never answered and has no status, though a
  recorder (its own reader) has it. A replay that answered it would step the loop once more than the node did,
  and every later answer would differ (the step interval, the MPCs' previous input): the replays skip it
  (`recording.replay_inputs.NodeClock.took`).
* A node behind takes a preview later than its publication, and a preview's age at a tick
  (``reference_timeout_s``) counts from when the node took it: every status names that clock
  (``preview_clock_ns``) and the replays hand the preview on at it (`PreviewFeed.feed_used`). At its publication,
  the ticks it was more than the timeout old for go unanswered in the replay where the node stepped.

Here a `ControllerLoop` with a realtime fleet's settings (reference timeout 0.2 s) plays the node on a scripted run
(`test_replay_settings`: a preview every 10 periods): six odometries are replaced before the node takes them, the
preview of 0.6 s is taken 60 ms after its publication and the two after it are lost, so that six ticks answered
from it are 203-253 ms after its publication (143-193 ms after the node took it). Every odometry is recorded, with
the node's answers and statuses. The truth is the node's own answers: `regress_bag` reproduces every one
(deviation 0), and neither without the skip nor with the previews at their publication.
"""

from __future__ import annotations

import pytest
from rclpy.serialization import serialize_message

from robotino_geom_mpc.loop.controller_loop import ControllerLoop
from robotino_geom_mpc.loop.events import Command, Now
from robotino_geom_mpc.recording import replay_inputs
from robotino_geom_mpc.recording.regress import regress_bag
from robotino_geom_mpc.ros.decode import odometry_input, preview_input
from robotino_geom_mpc.ros.messages import ns_to_stamp, preview_message
from test_replay_settings import CONTROL, EVERY, FLEET, MS, REF, ROBOT, START, _odometry, _record, _run_parameters, \
    node_messages

pytestmark = pytest.mark.unit

REPLACED = {40, 100, 101, 102, 130, 131}  # odometries a newer one replaced in the node's reader
TAKEN_LATE = {6: 60 * MS}  # preview -> how long after its publication the node took it
LOST = {7, 8}  # previews the node never had (nor the recorder)


def _run() -> tuple[list[tuple[int, str, bytes]], int]:
    """(publish time, topic, message) of the node's inputs (every odometry) and outputs (of those it took); the
    ticks it answered from a preview more than the timeout after its publication.
    """
    loop = ControllerLoop(ROBOT, CONTROL, Now(START, START), FLEET)
    sent: list[tuple[int, str, bytes]] = []
    events = [(START + j * EVERY * 10 * MS + MS + TAKEN_LATE.get(j, 0), 0, j) for j in range(16) if j not in LOST]
    events += [(START + 3 * MS + k * 10 * MS + MS, 1, k) for k in range(150)]
    published, late = 0, 0
    for clock, kind, index in sorted(events):
        if kind == 0:
            stamp = START + index * EVERY * 10 * MS
            msg = preview_message(REF, stamp - START, CONTROL.period_s, CONTROL.horizon + EVERY - 1)
            msg.header.stamp = ns_to_stamp(stamp)
            published = stamp + MS // 2
            sent.append((published, "/reference_preview", serialize_message(msg)))
            outputs = loop.on_input(preview_input(msg), Now(clock, clock))
        else:
            stamp = START + 3 * MS + index * 10 * MS
            msg = _odometry(stamp)
            sent.append((stamp + MS // 2, "/odom", serialize_message(msg)))
            if index in REPLACED:
                continue
            outputs = loop.on_input(odometry_input(msg), Now(clock, clock))
            late += any(isinstance(o, Command) for o in outputs) and \
                clock - published > FLEET.reference_timeout_s * 1e9
        sent += node_messages(clock, outputs)
    return sent, late


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    sent, late = _run()
    path = tmp_path_factory.mktemp("behind") / "bag"
    _record(path, sent, {**_run_parameters(), "reference_timeout_s": FLEET.reference_timeout_s})
    answered = sum(1 for _, topic, _ in sent if topic == "/wheel_voltages")
    assert sum(1 for _, topic, _ in sent if topic == "/odom") == 150
    return path, answered, late


def test_regress_replays_a_node_behind_exactly(recording):
    path, answered, late = recording
    assert late == 6  # ticks 203-253 ms after the preview's publication, 143-193 ms after the node took it
    result = regress_bag(path)
    assert result.compared == result.ticks == answered > 100 and result.max_deviation_v == 0.0, result


def test_answering_the_odometry_the_node_never_took_differs(recording, monkeypatch):
    path, answered, _ = recording
    monkeypatch.setattr(replay_inputs.NodeClock, "took", lambda self, stamp: True)  # as the replays did
    result = regress_bag(path)
    assert not result.passed and result.ticks > answered and result.max_deviation_v > 1e-6, result


def test_previews_at_their_publication_differ(recording, monkeypatch):
    path, answered, late = recording
    monkeypatch.setattr(replay_inputs.PreviewFeed, "feed_used", lambda self, last, taken_ns: self.feed(last))
    result = regress_bag(path)
    assert not result.passed and result.ticks == answered - late and result.max_deviation_v > 1e-6, result
