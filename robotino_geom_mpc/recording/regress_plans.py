"""Replay regression of a run recorded with plans (``plans``: a controller over a link): its plans recomputed.

A fresh `loop.controller_loop.ControllerLoop` with plans (the run parameters the recording stores, or a parameter
file) is given what the controller node got, in the order it got it: the plant's ``odom`` and ``command_applied``
messages, each topic in the order the recorder got it (one writer each: the node's order too), interleaved as the
node took them: before each odometry, the reports up to the count the node's status of that odometry gives
(``reports_received``; a recording without it: merged by publish time, the plant writing a radio packet's reports
before its odometry), and the ``reference_preview`` messages the node had by then (lockstep: those up to its stamp;
realtime: up to the one its diagnostics name), each odometry at the node's clock as it took it and after the
watchdog stops that fired before (`replay_inputs.NodeClock`). The loop makes the plans as the node did (reports
refused as it refuses them, the preview moved to the stamp, bumpless restarts, reordered and duplicated odometries
dropped). Each plan it makes is compared with the recorded plan of the same basis (``wheel_voltage_plan`` [V] or
``cmd_vel_plan`` [m/s, rad/s]): same code on the same inputs, the same floats (tolerance 1e-12). Plans the recorder
lacks are not compared.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
from typing import Any

import numpy as np

from robotino_geom_mpc.loop.events import AppliedReport, Now, PlanOut, Undecodable
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.replay_inputs import ControllerInputs, Deviations, NodeClock, PreviewFeed
from robotino_geom_mpc.recording.topics import by_publish_time, find_topic, plan_topic, stamp_ns
from robotino_geom_mpc.ros.plans import PlanMessageError, plan_of_message, report_of_message

__all__ = ["regress_plans"]

_BASIS_TOLERANCE_NS = 1000


def regress_plans(bag: BagReader, inputs: ControllerInputs, diags: list[tuple[int, Any]], robot: RobotinoParams,
                  control: ControlParams) -> tuple[Deviations, str]:
    """(the count: odometries planned from, plans compared, the largest deviation; the plan topic's name) of the
    replay (see the module docstring); BagError without plans or an odometry planned from.
    """
    found = plan_topic(bag)
    if found is None:
        raise BagError(f"{bag.path}: no plans in the recording")
    topic, interface = found
    recorded: dict[int, Any] = {}
    for _, msg in by_publish_time(bag, topic):
        recorded.setdefault(stamp_ns(msg.header.stamp), msg)
    # a plan's header holds its basis (odometry stamp ns * 1e-9) back in ns: at epoch times (1.8e9 s: 238 ns a
    # float's step) a few hundred ns off the odometry's stamp; the plan of an odometry is the one within 1 us
    bases = sorted(recorded)
    reports = by_publish_time(bag, find_topic(bag, "command_applied", "trajectory_msgs/msg/JointTrajectory", False))
    by_stamp, used, received = inputs.first_of, inputs.used, inputs.received
    ordered = sorted(by_stamp)  # lockstep: the previews by stamp
    lockstep = inputs.first_stamp in by_stamp
    replay = inputs.loop(robot, control, lockstep=lockstep, interface=interface, plans=True)
    previews = PreviewFeed(replay, inputs)
    node = NodeClock.read(diags)
    fed_stamps = taken = 0  # lockstep: previews handed on by stamp; reports handed on
    count = Deviations()

    def report(publish: int, msg: object) -> None:  # as the node's subscription hands it on
        try:
            event: AppliedReport | Undecodable = report_of_message(msg)
        except PlanMessageError as exc:
            event = Undecodable("command_applied", None, exc.reason, str(exc))
        replay.on_report(event, Now(publish, publish))

    if received:  # the node counted the reports it had got by each odometry: that order, whatever the recorder's
        events = ((p, 1, i) for i, (p, _) in enumerate(inputs.odom))
    else:  # a recording without the count: the recorder's order of the two topics
        events = heapq.merge(((p, 0, i) for i, (p, _) in enumerate(reports)),
                             ((p, 1, i) for i, (p, _) in enumerate(inputs.odom)), key=lambda e: e[:2])
    pending = iter(reports)
    for publish, kind, index in events:
        if kind == 0:
            report(publish, reports[index][1])
            continue
        stamp = stamp_ns(inputs.odom[index][1].header.stamp)
        if not lockstep and not node.took(stamp):
            continue  # replaced by a newer one in the node's reader before it took it
        if stamp in received:
            for report_publish, report_msg in itertools.islice(pending, max(received[stamp] - taken, 0)):
                report(report_publish, report_msg)
                taken += 1
        if lockstep:  # the previews up to its stamp
            while fed_stamps < len(ordered) and ordered[fed_stamps] <= stamp:
                previews.give(by_stamp[ordered[fed_stamps]])
                fed_stamps += 1
        elif stamp in used:  # the previews up to the one it used
            previews.feed_used(by_stamp.get(used[stamp], previews.fed), inputs.preview_clock.get(stamp))
        now = node.take(replay, stamp, publish)
        inputs.follow_enable(replay, stamp, now)
        plans = [o.plan for o in replay.on_input(inputs.odometries[index], now) if isinstance(o, PlanOut)]
        if not plans:
            continue
        plan = plans[0]
        count.ticks += 1
        near = bisect.bisect_left(bases, stamp - _BASIS_TOLERANCE_NS)
        if near == len(bases) or bases[near] > stamp + _BASIS_TOLERANCE_NS:
            continue
        try:
            mine = plan_of_message(recorded[bases[near]], plan.period_s)
        except PlanMessageError:
            continue
        count.compare(stamp, float(np.max(np.abs(np.array(plan.entries) - np.array(mine.entries))))
                      if len(mine.entries) == len(plan.entries) else float("inf"))
    if count.ticks == 0:
        raise BagError(f"{bag.path}: no odometry the controller planned from in the recording")
    return count, topic.lstrip("/")
