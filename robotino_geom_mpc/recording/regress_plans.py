"""Replay regression of a run recorded with plans (``plans``: a controller over a link): its plans recomputed.

A fresh `loop.controller_loop.ControllerLoop` with plans (the run parameters the recording stores, or a parameter
file) is given what the controller node got, in the order it got it: the plant's ``odom`` and ``command_applied``
messages, each topic in the order the recorder got it (one writer each: the node's order too), interleaved as the
node took them: before each odometry, the reports up to the count the node's status of that odometry gives
(``reports_received``; a recording without it: merged by publish time, the plant writing a radio packet's reports
before its odometry), and the ``reference_preview`` messages the node had by then (lockstep: those up to its
stamp; realtime: up to the one its diagnostics name). The loop makes the plans as the node did (reports refused
as it refuses them, the preview moved to the stamp, bumpless restarts, reordered and duplicated odometries
dropped). Each plan it makes is compared with the recorded plan of the same basis (``wheel_voltage_plan`` [V] or
``cmd_vel_plan`` [m/s, rad/s]): same code on the same inputs, the same floats (tolerance 1e-12). Plans the
recorder lacks are not compared.
"""

from __future__ import annotations

import bisect
import heapq
import itertools
from typing import Any

import numpy as np

from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
from robotino_geom_mpc.loop.events import AppliedReport, Now, PlanOut, Undecodable
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.topics import by_publish_time, controller_diagnostics, find_topic, plan_topic, stamp_ns
from robotino_geom_mpc.ros.decode import odometry_input, preview_input
from robotino_geom_mpc.ros.plans import PlanMessageError, plan_of_message, report_of_message

__all__ = ["plan_topic", "regress_plans"]

_BASIS_TOLERANCE_NS = 1000


def regress_plans(bag: BagReader, robot: RobotinoParams, control: ControlParams,
                  tolerance: float) -> tuple[int, int, float, float | None, str]:
    """(odometries stepped, plans compared, largest deviation, its time after the first odometry [s], the plan
    topic's name) of the replay (see the module docstring); BagError without odometry or plans.
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
    odom = by_publish_time(bag, find_topic(bag, "odom", "nav_msgs/msg/Odometry"))
    reports = by_publish_time(bag, find_topic(bag, "command_applied", "trajectory_msgs/msg/JointTrajectory", False))
    previews = by_publish_time(bag, find_topic(bag, "reference_preview", "trajectory_msgs/msg/MultiDOFJointTrajectory"))
    if not odom:
        raise BagError(f"{bag.path}: no odometry the controller planned from in the recording")
    by_stamp: dict[int, int] = {}  # preview stamp -> index of its first message (publish order)
    for j, (_, msg) in enumerate(previews):
        by_stamp.setdefault(stamp_ns(msg.header.stamp), j)
    ordered = sorted(by_stamp)  # lockstep: the previews by stamp
    used, received = _diagnosed(bag)
    first = stamp_ns(odom[0][1].header.stamp)
    lockstep = first in by_stamp
    replay = ControllerLoop(robot, control, Now(odom[0][0], odom[0][0]), lockstep=lockstep, interface=interface,
                            plans=True, odom_frame=previews[0][1].header.frame_id if previews else "odom",
                            listeners=QUIET)
    fed, fed_stamps = -1, 0  # previews handed on (realtime: publish order; lockstep: by stamp)
    ticks = compared = taken = 0
    worst, worst_stamp = 0.0, None

    def report(publish: int, msg: object) -> None:  # as the node's subscription hands it on
        try:
            event: AppliedReport | Undecodable = report_of_message(msg)
        except PlanMessageError as exc:
            event = Undecodable("command_applied", None, exc.reason, str(exc))
        replay.on_report(event, Now(publish, publish))

    if received:  # the node counted the reports it had got by each odometry: that order, whatever the recorder's
        events = ((p, 1, m) for p, m in odom)
    else:  # a recording without the count: the recorder's order of the two topics
        events = heapq.merge(((p, 0, m) for p, m in reports), ((p, 1, m) for p, m in odom), key=lambda e: e[:2])
    pending = iter(reports)
    for publish, kind, msg in events:
        if kind == 0:
            report(publish, msg)
            continue
        stamp = stamp_ns(msg.header.stamp)
        if stamp in received:
            for report_publish, report_msg in itertools.islice(pending, max(received[stamp] - taken, 0)):
                report(report_publish, report_msg)
                taken += 1
        if lockstep:  # the previews up to its stamp
            while fed_stamps < len(ordered) and ordered[fed_stamps] <= stamp:
                j = by_stamp[ordered[fed_stamps]]
                replay.on_input(preview_input(previews[j][1]), Now(previews[j][0], previews[j][0]))
                fed_stamps += 1
        elif stamp in used:  # the previews up to the one it used
            for j in range(fed + 1, by_stamp.get(used[stamp], fed) + 1):
                replay.on_input(preview_input(previews[j][1]), Now(previews[j][0], previews[j][0]))
            fed = max(fed, by_stamp.get(used[stamp], fed))
        plans = [o.plan for o in replay.on_input(odometry_input(msg), Now(publish, publish)) if isinstance(o, PlanOut)]
        if not plans:
            continue
        plan = plans[0]
        ticks += 1
        near = bisect.bisect_left(bases, stamp - _BASIS_TOLERANCE_NS)
        if near == len(bases) or bases[near] > stamp + _BASIS_TOLERANCE_NS:
            continue
        try:
            mine = plan_of_message(recorded[bases[near]], plan.period_s)
        except PlanMessageError:
            continue
        compared += 1
        deviation = float(np.max(np.abs(np.array(plan.entries) - np.array(mine.entries)))) \
            if len(mine.entries) == len(plan.entries) else float("inf")
        if worst_stamp is None or deviation > worst:
            worst, worst_stamp = deviation, stamp
    if ticks == 0:
        raise BagError(f"{bag.path}: no odometry the controller planned from in the recording")
    return ticks, compared, worst, None if worst_stamp is None else (worst_stamp - first) * 1e-9, topic.lstrip("/")


def _diagnosed(bag: BagReader) -> tuple[dict[int, int], dict[int, int]]:
    """Per odometry stamp, from the controller's diagnostics: the preview stamp it used and the reports it had
    received.
    """
    used: dict[int, int] = {}
    received: dict[int, int] = {}
    for _, msg in by_publish_time(bag, find_topic(bag, "diagnostics", "diagnostic_msgs/msg/DiagnosticArray", False)):
        values = controller_diagnostics(msg)
        if values is None:
            continue
        stamp = stamp_ns(msg.header.stamp)
        if values.get("preview_stamp_ns", "").isdigit():
            used.setdefault(stamp, int(values["preview_stamp_ns"]))
        if values.get("reports_received", "").isdigit():
            received.setdefault(stamp, int(values["reports_received"]))
    return used, received
