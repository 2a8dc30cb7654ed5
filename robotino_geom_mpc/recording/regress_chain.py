"""Replay regression of a chain recording (``chain.active``: the controller through the real driver's chain).

The controller node's chain mode (`nodes.chain_control`) steps a `control.chain_tracking.ChainTracker` on each
odometry with the newest reference preview it holds and the node clock's time of the step ("now": only the firmware
tick a command reaches depends on it, through the driver pass it catches), and publishes the twist on ``cmd_vel``
(no status per tick). A recording holds what the controller received and sent, with each message's publish time,
but not the node's two private readings: which preview it held (previews come every control period, odometry at
the driver's passes) and its clock at the step. Both are bounded by the recording: the step follows the odometry's
publish and precedes its answer's, and the preview it held was published before that answer and is no older than
the newest one published `RECEIVE_MARGIN_S` before the odometry.

`regress_chain` replays the recording through fresh trackers for every reading within those bounds (each preview
in the window, "now" at either end: within one driver pass both ends give the same tick), keeping the readings
whose twist equals the recorded answer (within the tolerance): the recorded answers themselves pin the unrecorded
readings, tick by tick, and a controller that differs, or a recorded twist that was changed, matches no reading
(the smallest deviation over the readings is reported). The answers are the recorded ``cmd_vel`` messages in the
order sent; besides them the node sends zero twists of its own (a refused input, its watchdog, its stop), each
noted in the tracker at its publish time: the node's status says which (each ``refused ...`` or ``watchdog: ...``
status follows its zero), and a last zero after the last odometry is the one it sends as it stops. While the
node is disabled (``~/enable`` false, ``start_enabled`` false) its status says ``disabled`` for each odometry: a zero
twist, noted, no step.

The chain's parameters are the controller's own, from its ``/parameter_events`` in the recording, else a
parameter file (``--chain-params``, `identify`'s), else the robocup-logistics preset (`chain_source` says which).
Limits: a watchdog that fired mid-run (stale odometry or reference) drops the node's preview; the replay keeps it.
"""

from __future__ import annotations

import copy
import os
from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robotino_geom_mpc.control.chain_controller import ChainControllerError
from robotino_geom_mpc.control.chain_tracking import ChainTracker
from robotino_geom_mpc.model.driver_chain import ChainError, ChainParams, chain_params
from robotino_geom_mpc.params.specs import CHAIN_SPECS, ControlParams
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.report import by_publish_time, find_topic, stamp_ns
from robotino_geom_mpc.ros.decode import InputRejected, odometry_state, preview_arrays

__all__ = ["BEAM", "RECEIVE_MARGIN_S", "ChainReplay", "chain_parameters", "regress_chain"]

RECEIVE_MARGIN_S = 0.01  # a preview published this long before an odometry had reached the node
BEAM = 32  # readings kept at once: the nearest to the recorded answers, then to the recorder's order
_CONTROLLER_NODE = "robotino_controller"
_STATUS_NAME = "robotino_geom_mpc: controller"


@dataclass(frozen=True)
class ChainReplay:
    """Outcome of `regress_chain`: odometries stepped, answers compared, the largest deviation [m/s, rad/s] and
    its stamp, and where the chain's parameters came from.
    """

    ticks: int
    compared: int
    max_deviation: float
    worst_stamp_s: float | None
    chain_source: str


@dataclass
class _Reading:
    """One reading of the unrecorded times: the tracker stepped on it and where it stands in the recording."""

    tracker: ChainTracker
    command: int = 0  # index of the next recorded cmd_vel not yet accounted for
    preview: int = -1  # index of the newest preview held (-1: none yet)
    last: int | None = None  # the node's last odometry used [ns]
    theta: float = 0.0
    ticks: int = 0
    compared: int = 0
    worst: float = 0.0
    worst_stamp: int | None = None
    unlikely: int = 0  # how far its previews are from those the recorder had received (its order)
    deviation: float | None = field(default=None, compare=False)  # of this odometry's answer, if compared

    def clone(self) -> _Reading:
        """A copy to step on its own (the chain's parameters and the controller's constants shared)."""
        c = self.tracker.controller
        shared = (c.chain, c._decay, c._b, c.clock.__class__)
        return copy.deepcopy(self, {id(item): item for item in shared})

    def key(self) -> tuple:
        """The state the next odometries see; readings that differ only in the preview held merge (the oldest
        kept: the newer ones are among its futures).
        """
        c = self.tracker.controller
        return (self.command, self.last, self.tracker.epoch_ns, repr(c.commands), c._plan_prev.tobytes(),
                c.clock.index)


def chain_parameters(bag: BagReader, chain_file: str | os.PathLike | None = None) -> tuple[ChainParams, str, bool]:
    """(the chain's parameters, their source, whether the controller's events say ``chain.active`` enabled).

    Raises
    ------
    BagError
        If the recorded or given values are not a valid chain.
    """
    values: dict[str, Any] = {}
    topic = find_topic(bag, "parameter_events", "rcl_interfaces/msg/ParameterEvent", False)
    for _, event in by_publish_time(bag, topic):
        if event.node.rsplit("/", 1)[-1] != _CONTROLLER_NODE:
            continue
        for parameter in (*event.new_parameters, *event.changed_parameters):
            if parameter.name.startswith("chain."):
                value = parameter.value
                values[parameter.name] = {1: value.bool_value, 2: value.integer_value, 3: value.double_value,
                                          4: value.string_value}.get(value.type)  # rcl_interfaces ParameterType
    active = values.pop("chain.active", None) == "enabled"
    try:
        if chain_file is not None:
            from robotino_geom_mpc.params.files import read_parameter_file

            given = read_parameter_file(chain_file, _CONTROLLER_NODE)
            return chain_params({k: v for k, v in given.items() if k.startswith("chain.") and k != "chain.active"},
                                where=str(chain_file)), str(chain_file), active
        known = {spec.name for spec in CHAIN_SPECS}
        if values and known <= values.keys():
            return chain_params({k: values[k] for k in known}, where="the controller's recorded parameters"), \
                "the controller's parameters in the recording", active
    except ChainError as exc:
        raise BagError(str(exc)) from None
    return chain_params(), "the robocup-logistics preset (the recording holds no chain.* of the controller)", active


def _statuses(bag: BagReader, commands: list[tuple[int, Any]]) -> tuple[dict[int, int], set[int]]:
    """From the node's status: per odometry stamp, how many times it said ``disabled`` (a zero twist, no step);
    and the indices of the recorded twists that were zeros of its own (each ``refused ...`` or ``watchdog: ...``
    status follows its zero twist: the last zero published before it).
    """
    held: dict[int, int] = {}
    own: set[int] = set()
    times = [p for p, _ in commands]
    topic = find_topic(bag, "diagnostics", "diagnostic_msgs/msg/DiagnosticArray", False)
    for publish, msg in by_publish_time(bag, topic):
        for status in msg.status:
            if status.name != _STATUS_NAME:
                continue
            if status.message == "disabled":
                stamp = stamp_ns(msg.header.stamp)
                held[stamp] = held.get(stamp, 0) + 1
            elif status.message.startswith(("refused", "watchdog")):
                i = bisect_left(times, publish) - 1
                while i >= 0 and (commands[i][1].any() or i in own):
                    i -= 1
                if i >= 0:
                    own.add(i)
    return held, own


def _with_log_times(bag: BagReader, topic: str | None) -> list[tuple[int, Any, int]]:
    """(publish time, message, the recorder's receive time) of a topic, in publish-time order."""
    logs = sorted((m.publish_time_ns, m.log_time_ns) for m in bag.messages([topic] if topic else []))
    return [(publish, msg, log) for (publish, msg), (_, log) in zip(by_publish_time(bag, topic), logs)]


def regress_chain(bag: BagReader, control: ControlParams, tolerance: float,
                  chain_file: str | os.PathLike | None = None) -> ChainReplay:
    """Replay a chain recording (the module docstring); BagError without odometry or ``cmd_vel``."""
    chain, source, _ = chain_parameters(bag, chain_file)
    odom = _with_log_times(bag, find_topic(bag, "odom", "nav_msgs/msg/Odometry"))
    previews = _with_log_times(bag, find_topic(bag, "reference_preview",
                                               "trajectory_msgs/msg/MultiDOFJointTrajectory"))
    commands = [(p, np.array((m.linear.x, m.linear.y, m.angular.z)))
                for p, m in by_publish_time(bag, find_topic(bag, "cmd_vel", "geometry_msgs/msg/Twist"))]
    if not odom:
        raise BagError(f"{bag.path}: no odometry in the recording")
    preview_t = [p for p, _, _ in previews]
    preview_log = sorted(log for _, _, log in previews)
    margin = round(RECEIVE_MARGIN_S * 1e9)
    held, own = _statuses(bag, commands)
    if commands and not commands[-1][1].any() and commands[-1][0] > odom[-1][0]:
        own.add(len(commands) - 1)  # the zero the node sends as it stops (after the last odometry)
    arrays: dict[int, Any] = {}  # preview index -> (stamp, positions, velocities, accelerations) or None (refused)

    def preview(j: int, theta: float) -> Any:
        if j not in arrays:
            msg = previews[j][1]
            try:
                arrays[j] = (stamp_ns(msg.header.stamp), *preview_arrays(msg, control.horizon, theta))
            except InputRejected:
                arrays[j] = None
        return arrays[j]

    def own_zero(r: _Reading) -> _Reading | None:
        """`r` with the next recorded twist taken as a zero of the node's own (noted), None if it is not a zero."""
        if r.command >= len(commands) or commands[r.command][1].any():
            return None
        z = r.clone()
        z.tracker.note_zero(commands[r.command][0])
        z.command += 1
        return z

    def expand(r: _Reading, publish: int, stamp: int, msg: Any, recorded_preview: int, disabled: bool
               ) -> list[_Reading]:
        r.deviation = None
        while r.command in own:  # the zeros the node sent of its own before this odometry
            r = own_zero(r)  # type: ignore[assignment]
        if r.last is not None and stamp < r.last:
            return [r]  # an older stamp than the last used: the node drops it
        try:
            X = odometry_state(msg, r.theta)
        except InputRejected:  # refused: the node sends a zero of its own
            return [z for z in (own_zero(r),) if z is not None] or [r]
        if disabled:  # a zero answer, noted, no step
            z = own_zero(r)
            if z is None:
                return []
            z.last, z.theta = stamp, X[4]
            return [z]
        out = []
        newest = bisect_right(preview_t, publish - margin) - 1  # held by the node for sure
        if r.preview < 0 and newest < 0:  # perhaps no preview yet: no answer
            waiting = copy.copy(r)
            waiting.theta = X[4]
            waiting.unlikely += recorded_preview >= 0  # the recorder had one
            out.append(waiting)
        if r.command < len(commands) and commands[r.command][0] > publish:  # an answer follows its odometry
            answer_t, recorded = commands[r.command]
            for j in range(max(newest, r.preview, 0), bisect_left(preview_t, answer_t)):
                held_preview = preview(j, r.theta)
                if held_preview is None:
                    continue
                seen = None
                for now in (publish, answer_t):
                    s = r.clone()
                    try:
                        twist = np.array(s.tracker.step(stamp, now, X, held_preview))
                    except ChainControllerError:
                        continue
                    if seen is not None and s.tracker.controller.commands == seen:
                        continue  # the same tick either way
                    seen = s.tracker.controller.commands
                    s.command, s.preview, s.last, s.theta = r.command + 1, j, stamp, X[4]
                    s.unlikely += abs(j - recorded_preview)  # the recorder's order stands for the node's
                    s.ticks += 1
                    s.compared += 1
                    s.deviation = float(np.max(np.abs(twist - recorded)))
                    if s.worst_stamp is None or s.deviation > s.worst:
                        s.worst, s.worst_stamp = s.deviation, stamp
                    out.append(s)
        return out

    readings = [_Reading(ChainTracker(chain, control.period_s))]
    for publish, msg, log in odom:
        stamp = stamp_ns(msg.header.stamp)
        recorded_preview = bisect_left(preview_log, log) - 1
        disabled = held.get(stamp, 0) > 0  # the node's status said so for this odometry
        if disabled:
            held[stamp] -= 1
        expanded = [e for r in readings for e in expand(r, publish, stamp, msg, recorded_preview, disabled)]
        matching = [e for e in expanded if e.deviation is None or e.deviation <= tolerance]
        if not matching:  # no reading gives the recorded answer: the nearest goes on, its deviation counted
            matching = [min(expanded, key=lambda e: e.deviation if e.deviation is not None else np.inf)] \
                if expanded else readings
        unique: dict[tuple, _Reading] = {}
        for e in sorted(matching, key=lambda e: (e.worst, e.unlikely, e.preview)):
            unique.setdefault(e.key(), e)
        readings = list(unique.values())[:BEAM]
    best = min(readings, key=lambda r: (r.worst, -r.compared))
    first = stamp_ns(odom[0][1].header.stamp)
    return ChainReplay(best.ticks, best.compared, best.worst,
                       None if best.worst_stamp is None else (best.worst_stamp - first) * 1e-9, source)
