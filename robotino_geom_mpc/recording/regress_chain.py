"""Replay regression of a chain recording (``chain.active``: the controller through the real driver's chain).

The controller node's chain mode (`loop.controller_loop.ControllerLoop` with ``chain``) steps a
`control.chain_tracking.ChainTracker` on each odometry with the newest reference preview it holds and the node
clock's time of the step ("now": only the firmware tick a command reaches depends on it, through the driver pass it
catches), and publishes the twist on ``cmd_vel``. Every zero twist it sends (a refused input, its watchdog, while
disabled) is noted in the tracker's command model at the clock.

A recording whose controller statuses carry the clock (``clock_ns``; its status per step, message ``chain``, names
the preview used, ``preview_stamp_ns``) replays exactly: one fresh `ControllerLoop` gets every odometry at the
clock its status names, the previews up to the one named, the watchdog where its status says it fired; each twist it
answers is compared with the recorded ``cmd_vel`` message of the same input. The node publishes an input's commands
(twists and zeros), then its status, in one callback, and publish times are the publisher's source times: the last
commands published before a status are its input's. Matched through the statuses, not counted from the first
command: the recorder subscribes topic by topic, so a recording may begin with answers to odometries it lacks
(``cmd_vel`` subscribed before ``odom`` and ``diagnostics``), which no replay gives.

Older recordings (no statuses: the chain controller of ec8bd99 published none) hold what the controller received
and sent, with each message's publish time, but not the node's two private readings: which preview it held
(previews come every control period, odometry at the driver's passes) and its clock at the step. Both are bounded
by the recording: the step follows the odometry's publish and precedes its answer's, and the preview it held was
published before that answer and is no older than the newest one published `RECEIVE_MARGIN_S` before the
odometry. `regress_chain` then replays the recording through fresh controller loops for every reading within
those bounds (each preview in the window, "now" at either end: within one driver pass both ends give the same
tick), keeping the readings whose twist equals the recorded answer (within the tolerance): the recorded answers
themselves pin the unrecorded readings, tick by tick, and a controller that differs, or a recorded twist that was
changed, matches no reading (the smallest deviation over the readings is reported). A refused odometry's zero is
noted at the recorded zero's publish time.

The chain's parameters are the controller's own, from its ``/parameter_events`` in the recording, else a
parameter file (``--chain-params``, `identify`'s), else the robocup-logistics preset (`chain_source` says which).
Limits: the controller node's own parameters are the loop's defaults; the watchdog of an exact replay decides on
the node clock (the node's on steady time).
"""

from __future__ import annotations

import copy
import os
from bisect import bisect_left, bisect_right
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robotino_geom_mpc.loop.controller_loop import ControllerLoop
from robotino_geom_mpc.loop.events import Command, Now, Output, Zero
from robotino_geom_mpc.model.driver_chain import ChainError, ChainParams, chain_params
from robotino_geom_mpc.params.specs import CHAIN_SPECS, ControlParams, RobotinoParams
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.replay_inputs import ControllerInputs, Deviations, PreviewFeed
from robotino_geom_mpc.recording.topics import by_publish_time, find_topic, stamp_ns
from robotino_geom_mpc.ros.controller_cdr import STATUS_NAME

__all__ = ["BEAM", "RECEIVE_MARGIN_S", "WATCHDOG_STALE_NS", "chain_parameters", "regress_chain"]

RECEIVE_MARGIN_S = 0.01  # a preview published this long before an odometry had reached the node
BEAM = 32  # readings kept at once: the nearest to the recorded answers, then to the recorder's order
WATCHDOG_STALE_NS = 10**12  # a recorded watchdog stop replayed on a watchdog clock this far on: stale for sure
_CONTROLLER_NODE = "robotino_controller"


@dataclass
class _Reading:
    """One reading of the unrecorded times: a controller loop stepped on it and where it stands in the recording."""

    loop: ControllerLoop
    command: int = 0  # index of the next recorded cmd_vel not yet accounted for
    preview: int = -1  # index of the newest preview held (-1: none yet)
    count: Deviations = field(default_factory=Deviations)
    unlikely: int = 0  # how far its previews are from those the recorder had received (its order)
    deviation: float | None = field(default=None, compare=False)  # of this odometry's answer, if compared

    def clone(self) -> _Reading:
        """A copy to step on its own (the parameters, the settings, the unused MPC, the stateless pairing and the
        chain controller's constants shared).
        """
        loop = self.loop
        assert loop.chain is not None
        c = loop.chain.controller
        shared = (loop.robot, loop.control, loop.controller, loop.settings, loop.listeners, loop.pairing, c.chain,
                  c._decay, c._b, c.clock.__class__)
        return copy.deepcopy(self, {id(item): item for item in shared})

    def key(self) -> tuple:
        """The state the next odometries see; readings that differ only in the preview held merge (the oldest
        kept: the newer ones are among its futures).
        """
        assert self.loop.chain is not None
        tracker = self.loop.chain
        c = tracker.controller
        return (self.command, self.loop.last_odom_ns, tracker.epoch_ns, repr(c.commands), c._plan_prev.tobytes(),
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


@dataclass(frozen=True)
class _Status:
    """One status of the controller with its clock: publish time, header stamp, message, key/values."""

    publish: int
    stamp: int
    message: str
    values: dict[str, str]

    @property
    def clock(self) -> int:
        return int(self.values["clock_ns"])


def _statuses(diags: list[tuple[int, Any]]) -> list[_Status]:
    """The controller's statuses among `diags` that carry its clock (``clock_ns``), in publish order."""
    out = []
    for publish, msg in diags:
        for status in msg.status:
            if status.name != STATUS_NAME:
                continue
            values = {kv.key: kv.value for kv in status.values}
            if values.get("clock_ns", "").isdigit():
                out.append(_Status(publish, stamp_ns(msg.header.stamp), status.message, values))
    return out


def regress_chain(bag: BagReader, inputs: ControllerInputs, twists: list[tuple[int, Any]],
                  diags: list[tuple[int, Any]], robot: RobotinoParams, control: ControlParams, tolerance: float,
                  chain_file: str | os.PathLike | None = None) -> tuple[Deviations, str]:
    """Replay a chain recording (the module docstring) whose recorded ``cmd_vel`` are `twists` and diagnostics
    `diags`: the count and where the chain's parameters came from.
    """
    chain, source, _ = chain_parameters(bag, chain_file)
    commands = [(p, np.array((m.linear.x, m.linear.y, m.angular.z))) for p, m in twists]
    loop = inputs.loop(robot, control, interface="cmd_vel", chain=chain)
    statuses = _statuses(diags)
    if statuses:
        return _exact(loop, inputs, commands, statuses), source
    return _search(loop, inputs, commands, tolerance), source


def _commands_of(statuses: list[_Status], commands: list) -> list[list[np.ndarray]]:
    """Per status: the commands published after the status before it and up to it (its input's are the last)."""
    times = [publish for publish, _ in commands]
    out, since = [], 0
    for status in statuses:
        upto = bisect_right(times, status.publish, lo=since)
        out.append([values for _, values in commands[since:upto]])
        since = upto
    return out


def _exact(loop: ControllerLoop, inputs: ControllerInputs, commands: list, statuses: list[_Status]) -> Deviations:
    """The replay of a recording with the clock in its statuses: one loop, the recorded times.

    The node's inputs in the order of its clock: each odometry at the clock of its status (one without a status
    had no answer: not replayed), a refused preview at the clock of its refusal, each watchdog stop at its clock
    (stale by then for sure: the node decided on its steady clock); an accepted preview when a step names it
    (received by then, its stamp checked at its publish time).
    """
    by_odometry: dict[int, deque[int]] = {}  # odometry stamp -> its statuses (two samples of a stamp: two)
    preview_stamps = [stamp_ns(msg.header.stamp) for _, msg in inputs.previews]
    first_of = inputs.first_of
    # (clock, kind, index, its status or -1): kind 0 a refused preview, 1 an odometry, 2 a watchdog stop
    timeline: list[tuple[int, int, int, int]] = []
    refused: set[int] = set()
    for k, status in enumerate(statuses):
        if status.message.startswith("watchdog"):
            timeline.append((status.clock, 2, k, k))
        elif status.message.startswith("refused reference_preview") and status.stamp in first_of:
            refused.add(first_of[status.stamp])
            timeline.append((status.clock, 0, first_of[status.stamp], k))
        elif status.message in ("chain", "disabled") or status.message.startswith(("refused odom", "dropped odom",
                                                                                    "refused input")):
            by_odometry.setdefault(status.stamp, deque()).append(k)
    for i, (publish, msg) in enumerate(inputs.odom):
        queue = by_odometry.get(stamp_ns(msg.header.stamp))
        entry = queue.popleft() if queue else -1
        timeline.append((publish if entry < 0 else statuses[entry].clock, 1, i, entry))
    timeline.sort()
    sent = _commands_of(statuses, commands)
    previews = PreviewFeed(loop, inputs)
    count = Deviations()

    def take(outputs: list[Output], stamp: int, status: int) -> None:
        """Compare the twists of an input's `outputs` with the commands recorded before its `status` (-1: none)."""
        answers = [out for out in outputs if isinstance(out, (Command, Zero))]
        before = sent[status] if status >= 0 else []
        recorded = before[len(before) - len(answers):] if len(before) >= len(answers) else []
        for j, out in enumerate(answers):
            if not isinstance(out, Command):
                continue
            count.ticks += 1
            if recorded:
                count.compare(stamp, float(np.max(np.abs(np.array(out.values) - recorded[j]))))

    for clock, kind, index, k in timeline:
        if kind == 0:
            take(loop.on_input(inputs.preview_events[index], Now(clock, clock)), preview_stamps[index], k)
            continue
        if kind == 2:
            take(loop.on_watchdog(Now(clock, clock + WATCHDOG_STALE_NS)), clock, k)
            continue
        msg = inputs.odom[index][1]
        mine = None if k < 0 else statuses[k]
        if mine is not None and mine.message in ("chain", "disabled") and \
                loop.enabled != (mine.message == "chain"):
            loop.on_enable(mine.message == "chain", Now(clock, clock))
        if mine is None:  # no status: no answer (no preview yet, a stale one, or the node stopping first)
            continue
        last = first_of.get(int(mine.values["preview_stamp_ns"]), previews.fed) if mine.message == "chain" \
            else previews.fed
        for j, outputs in previews.up_to(last, clock, refused):
            take(outputs, preview_stamps[j], -1)
        take(loop.on_input(inputs.odometries[index], Now(clock, clock)), stamp_ns(msg.header.stamp), k)
    return count


def _search(loop: ControllerLoop, inputs: ControllerInputs, commands: list, tolerance: float) -> Deviations:
    """The bounded search over the unrecorded readings (the module docstring), each a `ControllerLoop`."""
    preview_t = [p for p, _ in inputs.previews]
    preview_log = sorted(inputs.preview_log_ns)
    margin = round(RECEIVE_MARGIN_S * 1e9)

    def hold(base: _Reading, j: int) -> bool:
        """`base` (a copy of its own) moved on to hold the previews up to `j`; False if the loop refused one (the
        node's zero: no reading).
        """
        for k in range(base.preview + 1, j + 1):
            base.preview = k
            if any(isinstance(o, Zero) for o in base.loop.on_input(inputs.preview_events[k],
                                                                  Now(preview_t[k], preview_t[k]))):
                return False
        return True

    def expand(r: _Reading, index: int, recorded_preview: int) -> list[_Reading]:
        r.deviation = None
        publish, msg = inputs.odom[index]
        stamp = stamp_ns(msg.header.stamp)
        odometry = inputs.odometries[index]
        out = []
        newest = bisect_right(preview_t, publish - margin) - 1  # held by the node for sure
        if r.preview < 0 and newest < 0:  # perhaps no preview yet: no answer
            waiting = r.clone()
            waiting.loop.on_input(odometry, Now(publish, publish))
            waiting.unlikely += recorded_preview >= 0  # the recorder had one
            out.append(waiting)
        if r.command < len(commands) and commands[r.command][0] > publish:  # an answer follows its odometry
            answer_t, recorded = commands[r.command]
            held = r.clone()
            for j in range(max(newest, r.preview, 0), bisect_left(preview_t, answer_t)):
                if not hold(held, j):
                    break
                seen = None
                for now in (publish, answer_t):
                    s = held.clone()
                    answer = s.loop.on_input(odometry, Now(now, publish))
                    twists = [o.values for o in answer if isinstance(o, Command)]
                    if any(isinstance(o, Zero) for o in answer):  # refused: the node's zero, noted when it went out
                        z = r.clone()
                        z.loop.on_input(odometry, Now(answer_t, publish))
                        z.command += 1
                        return [z] if not recorded.any() else [r]
                    if not twists:
                        break  # dropped (an older stamp) or no step: no answer
                    assert s.loop.chain is not None
                    if seen is not None and s.loop.chain.controller.commands == seen:
                        continue  # the same tick either way
                    seen = s.loop.chain.controller.commands
                    s.command = r.command + 1
                    s.unlikely += abs(j - recorded_preview)  # the recorder's order stands for the node's
                    s.count.ticks += 1
                    s.deviation = float(np.max(np.abs(np.array(twists[0]) - recorded)))
                    s.count.compare(stamp, s.deviation)
                    out.append(s)
        if not out:  # no answer expected (e.g. an older stamp the node drops): the loop takes it all the same
            r.loop.on_input(odometry, Now(publish, publish))
            return [r]
        return out

    readings = [_Reading(loop)]
    for index, log in enumerate(inputs.odom_log_ns):
        recorded_preview = bisect_left(preview_log, log) - 1
        expanded = [e for r in readings for e in expand(r, index, recorded_preview)]
        matching = [e for e in expanded if e.deviation is None or e.deviation <= tolerance]
        if not matching:  # no reading gives the recorded answer: the nearest goes on, its deviation counted
            matching = [min(expanded, key=lambda e: e.deviation if e.deviation is not None else np.inf)] \
                if expanded else readings
        unique: dict[tuple, _Reading] = {}
        for e in sorted(matching, key=lambda e: (e.count.worst, e.unlikely, e.preview)):
            unique.setdefault(e.key(), e)
        readings = list(unique.values())[:BEAM]
    return min(readings, key=lambda r: (r.count.worst, -r.count.compared)).count
