"""Replay regression of a run recorded with plans (``plans``: a controller over a link): its plans recomputed.

A fresh `control.delay_compensation.DelayCompensatingController` (the run parameters the recording stores, or a
parameter file) is given what the controller node got, in the order it got it: the plant's ``odom`` and
``command_applied`` messages, each topic in the order the recorder got it (one writer each: the node's order
too), interleaved as the node took them: before each odometry, the reports up to the count the node's status of
that odometry gives (``reports_received``; a recording without it: merged by publish time, the plant writing a
radio packet's reports before its odometry), each refused as the node refuses it (`ros.plans.take_report`), the
receipts (`report_receipt`) and the
applied periods (`report_applied`) from the reports, and for each odometry newer than the last used the
``reference_preview`` of its stamp (lockstep) or the one its diagnostics name, moved to its stamp as the node
does (realtime), with the node's bumpless restarts where its diagnostics count one. Each plan it makes is compared
with the recorded plan of the same basis (``wheel_voltage_plan`` [V] or ``cmd_vel_plan`` [m/s, rad/s]): same
code on the same inputs, the same floats (tolerance 1e-12). Plans the recorder lacks are not compared.
"""

from __future__ import annotations

import bisect
import heapq
import itertools

import numpy as np

from robotino_geom_mpc.control.blend import ANGULAR_LIMIT_RADPS2, LINEAR_LIMIT_MPS2, BlendEngagement
from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController
from robotino_geom_mpc.control.motion_controller import ControllerInputError
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.topics import by_publish_time, controller_diagnostics, find_topic, plan_topic, stamp_ns
from robotino_geom_mpc.reference.trajectories import shift_preview
from robotino_geom_mpc.ros.decode import InputRejected, odometry_state, preview_arrays
from robotino_geom_mpc.ros.plans import PlanMessageError, plan_of_message, take_report

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
    recorded = {}
    for _, msg in by_publish_time(bag, topic):
        recorded.setdefault(stamp_ns(msg.header.stamp), msg)
    # a plan's header holds its basis (odometry stamp ns * 1e-9) back in ns: at epoch times (1.8e9 s: 238 ns a
    # float's step) a few hundred ns off the odometry's stamp; the plan of an odometry is the one within 1 us
    bases = sorted(recorded)
    odom = by_publish_time(bag, find_topic(bag, "odom", "nav_msgs/msg/Odometry"))
    reports = by_publish_time(bag, find_topic(bag, "command_applied", "trajectory_msgs/msg/JointTrajectory", False))
    previews: dict[int, object] = {}
    for _, msg in by_publish_time(bag, find_topic(bag, "reference_preview",
                                                  "trajectory_msgs/msg/MultiDOFJointTrajectory")):
        previews.setdefault(stamp_ns(msg.header.stamp), msg)
    used, engagements, received = _diagnosed(bag)
    controller = DelayCompensatingController(robot, control, interface)
    points = controller.preview_length
    blend = BlendEngagement(control.period_s, points)
    engaged, last, theta, first, newest = 0, None, 0.0, None, None
    ticks = compared = taken = 0
    worst, worst_stamp = 0.0, None

    def take(msg: object) -> None:  # as the node's `ControllerPlans._on_report`
        try:
            take_report(controller, msg, newest)
        except PlanMessageError:
            pass

    if received:  # the node counted the reports it had got by each odometry: that order, whatever the recorder's
        events = ((p, 1, m) for p, m in odom)
    else:  # a recording without the count: the recorder's order of the two topics
        events = heapq.merge(((p, 0, m) for p, m in reports), ((p, 1, m) for p, m in odom), key=lambda e: e[:2])
    pending = iter(reports)
    for _, kind, msg in events:
        if kind == 0:
            take(msg)
            continue
        stamp = stamp_ns(msg.header.stamp)
        if stamp in received:
            for _, report_msg in itertools.islice(pending, max(received[stamp] - taken, 0)):
                take(report_msg)
                taken += 1
        if last is not None and stamp <= last:
            continue  # a duplicate or an older odometry: the node drops it
        preview = previews.get(used.get(stamp, stamp))
        if first is None:
            first = stamp
            if stamp in previews and 0 in previews and stamp not in engagements:  # lockstep: start at t = 0
                controller.start_at(*preview_arrays(previews[0], points, 0.0)[0][0].tolist())
        try:
            X = odometry_state(msg, theta)
            theta = X[4]
            if preview is None:
                continue
            positions, velocities, accelerations = preview_arrays(preview, points, theta)
        except InputRejected:
            continue
        dt = (stamp - stamp_ns(preview.header.stamp)) * 1e-9
        positions = shift_preview(positions, velocities, accelerations, dt)
        if engagements.get(stamp, engaged) > engaged:  # the node restarted bumplessly here
            engaged = engagements[stamp]
            controller.reset()
            blend.engage(stamp, X, positions[0], velocities[0] + dt * accelerations[0], accelerations[0],
                         LINEAR_LIMIT_MPS2, ANGULAR_LIMIT_RADPS2)
        offsets = blend.offsets(stamp)
        newest = stamp * 1e-9
        try:
            plan = controller.plan(newest, X, positions[1:] if offsets is None else positions[1:] + offsets)
        except ControllerInputError:
            continue
        last = stamp
        ticks += 1
        near = bisect.bisect_left(bases, stamp - _BASIS_TOLERANCE_NS)
        if plan is None or near == len(bases) or bases[near] > stamp + _BASIS_TOLERANCE_NS:
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


def _diagnosed(bag: BagReader) -> tuple[dict[int, int], dict[int, int], dict[int, int]]:
    """Per odometry stamp, from the controller's diagnostics: the preview stamp it used, its restarts so far and
    the reports it had received.
    """
    used, engagements, received = {}, {}, {}
    for _, msg in by_publish_time(bag, find_topic(bag, "diagnostics", "diagnostic_msgs/msg/DiagnosticArray", False)):
        values = controller_diagnostics(msg)
        if values is None:
            continue
        stamp = stamp_ns(msg.header.stamp)
        if values.get("preview_stamp_ns", "").isdigit():
            used.setdefault(stamp, int(values["preview_stamp_ns"]))
        if values.get("blend_engagements", "").isdigit():
            engagements.setdefault(stamp, int(values["blend_engagements"]))
        if values.get("reports_received", "").isdigit():
            received.setdefault(stamp, int(values["reports_received"]))
    return used, engagements, received
