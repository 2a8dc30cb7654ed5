"""Replay regression: a recording's odometry and reference previews through a fresh controller loop.

A fresh `loop.controller_loop.ControllerLoop` (the node's tick protocol), built from the run parameters the
recording stores (or a parameter file), is given what the controller node got, in the recorded order with the
recorded times (each message's publish time as the clock): every ``odom`` message once and the
``reference_preview`` messages the node had by then -- lockstep: the preview of the same stamp (the loop pairs
them); realtime: the previews up to the one the node's diagnostics name for the tick (``preview_stamp_ns``), else
those published before the next odometry (the ticks before the first preview the diagnostics name are not
answered: the node had no preview yet). The loop answers as the node did: the preview moved to the tick's stamp,
the step interval, the bumpless (re)starts, zero on a refused input. Its commands are compared with the recorded
``wheel_voltages`` answer of the tick (paired through the controller's ``diagnostics``, stamped with the tick, see
`report`). Deterministic code on identical inputs gives identical floats, so the tolerance is 1e-12 V. A cmd_vel
run (its controller sent twists on ``cmd_vel``, no ``wheel_voltages``) is compared the same way on the twist the
node sends (v_x, v_y [m/s], theta' [rad/s] in base_link; zero where the node refused the input), with the same
tolerance in those units. Runs with plans: `regress_plans`; chain runs: `regress_chain`.

The controller carries state from tick to tick (u(k-1) of the Delta-u form, the pose estimate), so the replay
needs every tick's inputs. In a lockstep recording (its first tick has a preview of the same stamp; the ticks are
one control period apart) it stops at the first tick whose odometry (the next stamp is more than 1.5 periods on)
or preview is missing from the recording, and says so (`RegressionResult.gap_at_s`). A recorder that fell behind
a fast lockstep loop can have lost samples; the ticks before the gap are still compared.

The node's watchdog stops (its ``watchdog: ...`` statuses) are replayed where they came. Limits: the controller
node's own parameters are not in the recording (the loop's defaults are used: blend limits, timeouts, tolerances);
a parameter change during the run (the node rebuilds its controller) is not replayed; such a recording shows a
deviation from that tick on.
"""

from __future__ import annotations

import math
import os
from bisect import bisect_left
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
from robotino_geom_mpc.loop.events import Command, Now, Zero
from robotino_geom_mpc.ros.controller_cdr import STATUS_NAME
from robotino_geom_mpc.ros.decode import odometry_input, preview_input
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.regress_chain import WATCHDOG_STALE_NS, chain_parameters, regress_chain
from robotino_geom_mpc.recording.regress_plans import plan_topic, regress_plans
from robotino_geom_mpc.recording.report import resolve_parameters
from robotino_geom_mpc.recording.topics import by_publish_time, controller_diagnostics, find_topic, stamp_ns

__all__ = ["RegressionResult", "regress_bag"]


@dataclass(frozen=True)
class RegressionResult:
    """Outcome of `regress_bag`.

    Attributes
    ----------
    ticks
        Odometry ticks stepped through the controller.
    compared
        Ticks with a recorded answer that was compared.
    max_deviation_v
        Largest |recomputed - recorded| voltage over all compared ticks [V].
    worst_time_s
        Tick time (relative to the first tick) of that deviation, or None.
    tolerance_v
        The tolerance of the verdict.
    gap_at_s
        Lockstep recordings: tick time (relative to the first tick) of the first tick whose odometry or
        preview the recording lacks, where the replay stopped; None if every tick's inputs are there.
    gap
        What is missing there (``"odom"`` or ``"reference_preview"``), or None.
    command
        The compared command topic: ``wheel_voltages`` (deviations in V) or ``cmd_vel`` (in m/s and rad/s), or
        the plans of a run with plans, ``wheel_voltage_plan`` (V) or ``cmd_vel_plan`` (`regress_plans`).
    chain_source
        A chain recording (`regress_chain`): where the chain's parameters came from; else None.
    """

    ticks: int
    compared: int
    max_deviation_v: float
    worst_time_s: float | None
    tolerance_v: float
    gap_at_s: float | None = None
    gap: str | None = None
    command: str = "wheel_voltages"
    chain_source: str | None = None

    @property
    def passed(self) -> bool:
        return self.compared > 0 and self.max_deviation_v <= self.tolerance_v

    @property
    def unit(self) -> str:
        """The unit of the deviations and the tolerance: ``V``, or ``m/s, rad/s`` for a cmd_vel twist."""
        return "V" if self.command.startswith("wheel_voltage") else "m/s, rad/s"


def regress_bag(
    bag: BagReader | str | os.PathLike,
    params_file: str | os.PathLike | None = None,
    tolerance_v: float = 1e-12,
    chain_file: str | os.PathLike | None = None,
) -> RegressionResult:
    """Recompute the controller's voltages (a cmd_vel run: twists) from a recording and compare them to the
    recorded ones.

    A chain recording (the controller's recorded parameters say ``chain.active`` enabled, or `chain_file`, the
    chain's parameter file, is given, or a cmd_vel recording holds no tracking status of the controller: the
    chain mode publishes none) is replayed by `regress_chain`.

    Raises
    ------
    BagError
        If the recording lacks ``odom``, ``reference_preview`` or
        ``wheel_voltages`` (a cmd_vel run: ``cmd_vel``).
    """
    if not math.isfinite(tolerance_v) or tolerance_v < 0.0:
        raise BagError(f"tolerance must be finite and >= 0, got {tolerance_v!r}")
    if not isinstance(bag, BagReader):
        bag = BagReader(bag)
    robot, control, _, _ = resolve_parameters(bag, params_file)
    if plan_topic(bag) is not None:  # a run with plans (over a link): its plans recomputed (`regress_plans`)
        ticks, compared, worst, worst_time, topic = regress_plans(bag, robot, control, tolerance_v)
        return RegressionResult(ticks, compared, worst, worst_time, float(tolerance_v), command=topic)
    odom = by_publish_time(bag, find_topic(bag, "odom", "nav_msgs/msg/Odometry"))
    previews = by_publish_time(bag, find_topic(bag, "reference_preview", "trajectory_msgs/msg/MultiDOFJointTrajectory"))
    command = find_topic(bag, "wheel_voltages", "std_msgs/msg/Float64MultiArray", False)
    twists = command is None  # a cmd_vel run: the controller's twists
    if twists and find_topic(bag, "cmd_vel", "geometry_msgs/msg/Twist", False) is None:
        raise BagError(f"{bag.path}: no 'wheel_voltages' (std_msgs/msg/Float64MultiArray) nor 'cmd_vel' "
                       "(geometry_msgs/msg/Twist) topic in the recording: no controller command to compare")
    voltages = by_publish_time(bag, command or find_topic(bag, "cmd_vel", "geometry_msgs/msg/Twist"))
    diags = by_publish_time(bag, find_topic(bag, "diagnostics", "diagnostic_msgs/msg/DiagnosticArray", False))
    if twists and (chain_file is not None or chain_parameters(bag)[2]
                   or not any(controller_diagnostics(msg) is not None for _, msg in diags)):
        chain = regress_chain(bag, robot, control, tolerance_v, chain_file)
        return RegressionResult(chain.ticks, chain.compared, chain.max_deviation, chain.worst_stamp_s,
                                float(tolerance_v), command="cmd_vel", chain_source=chain.chain_source)
    volt_t = [p for p, _ in voltages]
    answers: dict[int, np.ndarray] = {}  # tick stamp -> recorded voltages
    used: dict[int, int] = {}  # tick stamp -> stamp of the preview the node used (its diagnostics say)
    for publish, msg in diags:
        values = controller_diagnostics(msg)
        if values is None:
            continue
        if values.get("preview_stamp_ns", "").isdigit():
            used.setdefault(stamp_ns(msg.header.stamp), int(values["preview_stamp_ns"]))
        i = bisect_left(volt_t, publish) - 1
        if i >= 0:
            answers.setdefault(stamp_ns(msg.header.stamp), _command_values(voltages[i][1], twists))
    # the node's watchdog stops (realtime: zero, the stamps and the preview forgotten, a restart at the data's return)
    stops = deque((publish, stamp_ns(msg.header.stamp)) for publish, msg in diags
                  if any(s.name == STATUS_NAME and s.message.startswith("watchdog") for s in msg.status))
    by_stamp: dict[int, int] = {}  # preview stamp -> index of its first message (publish order)
    for j, (_, msg) in enumerate(previews):
        by_stamp.setdefault(stamp_ns(msg.header.stamp), j)
    prev_t = [p for p, _ in previews]
    if not odom:
        raise BagError(f"{bag.path}: no odometry tick in the recording")
    first_stamp = stamp_ns(odom[0][1].header.stamp)
    # the first tick has a preview of its own stamp; realtime stamps follow the plant's timer, late or not,
    # so only a lockstep recording is tested for gaps
    lockstep = first_stamp in by_stamp
    replay = ControllerLoop(robot, control, Now(odom[0][0], odom[0][0]), lockstep=lockstep,
                            interface="cmd_vel" if twists else "voltages",
                            odom_frame=previews[0][1].header.frame_id if previews else "odom", listeners=QUIET)
    fed = -1  # previews handed to the loop so far (publish order)
    seen: set[int] = set()
    ticks = compared = 0
    worst, worst_stamp = 0.0, None
    previous = None
    gap = None
    period_ns = round(control.period_s * 1e9)
    for index, (publish, msg) in enumerate(odom):
        stamp = stamp_ns(msg.header.stamp)
        if stamp in seen:
            continue  # a lockstep tick the plant resent: the node answers it once
        seen.add(stamp)
        if lockstep and previous is not None and 2 * (stamp - previous) > 3 * period_ns:
            gap = (previous + period_ns, "odom")
            break
        if lockstep and stamp not in by_stamp:
            gap = (stamp, "reference_preview")
            break
        previous = stamp
        while stops and stops[0][0] < publish:  # stale by then for sure (the node decided on its steady clock)
            clock = stops.popleft()[1]
            replay.on_watchdog(Now(clock, clock + WATCHDOG_STALE_NS))
        # the previews the node had by this odometry: lockstep that of its stamp; realtime up to the one its
        # diagnostics name, else those published before its answer (none before the first one named)
        if lockstep:
            j = by_stamp[stamp]
            replay.on_input(preview_input(previews[j][1]), Now(prev_t[j], prev_t[j]))
        else:
            if stamp in used:
                last = by_stamp.get(used[stamp], fed)
            elif ticks == 0 and used:
                last = fed
            else:
                answer_publish = odom[index + 1][0] if index + 1 < len(odom) else publish + 10**9
                last = bisect_left(prev_t, answer_publish) - 1
            for j in range(fed + 1, last + 1):
                replay.on_input(preview_input(previews[j][1]), Now(prev_t[j], prev_t[j]))
            fed = max(fed, last)
        out = replay.on_input(odometry_input(msg), Now(publish, publish))
        expected = next((o.values for o in out if isinstance(o, Command) and o.stamp_ns == stamp), None)
        if expected is None:
            if not any(isinstance(o, Zero) for o in out):
                continue  # no answer: the node had no preview yet, or dropped the odometry
            expected = (0.0, 0.0, 0.0)  # refused: zero output
        ticks += 1
        recorded = answers.get(stamp)
        if recorded is None or recorded.shape != (3,):
            continue
        compared += 1
        deviation = float(np.max(np.abs(np.asarray(expected) - recorded)))
        if worst_stamp is None or deviation > worst:
            worst, worst_stamp = deviation, stamp
    if ticks == 0:
        raise BagError(f"{bag.path}: no odometry tick in the recording")
    worst_time = None if worst_stamp is None else (worst_stamp - first_stamp) * 1e-9
    gap_at = None if gap is None else (gap[0] - first_stamp) * 1e-9
    return RegressionResult(ticks, compared, worst, worst_time, float(tolerance_v), gap_at,
                            None if gap is None else gap[1], "cmd_vel" if twists else "wheel_voltages")


def _command_values(msg: Any, twist: bool) -> np.ndarray:
    """The recorded command: wheel voltages, or a Twist's (linear.x, linear.y, angular.z)."""
    if twist:
        return np.array((msg.linear.x, msg.linear.y, msg.angular.z))
    return np.array(msg.data)
