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
changed, matches no reading (the smallest deviation over the readings is reported; a reading that left a recorded
answer behind, sent before its odometry, matches no more). A refused odometry's zero is noted at the recorded zero's
publish time. The readings are stepped best first (`_kept`): while many match (a robot at rest answers zero whatever
the reading), the search stops stepping once the `BEAM` it keeps are known, and keeps those that stepping every
reading would keep.

The chain's parameters are a parameter file's if one is given (``--chain-params``, `identify`'s), else the
controller's own from its ``/parameter_events`` in the recording, else those the recorder stored with the run
(`topics.run_parameters`: the launch and `run` give the recorder the controller's ``chain.*``), else the
robocup-logistics preset (`chain_source` says which).
The loop's own settings are the node's as `replay_inputs.loop_settings` finds them. Limits: the watchdog of an
exact replay decides on the node clock (the node's on steady time).
"""

from __future__ import annotations

import copy
import heapq
import math
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
from robotino_geom_mpc.recording.replay_inputs import ODOMETRY_STATUSES, WATCHDOG_STALE_NS, ControllerInputs, \
    Deviations, PreviewFeed
from robotino_geom_mpc.recording.topics import CONTROLLER_NODE, controller_parameters, run_parameters, stamp_ns
from robotino_geom_mpc.ros.controller_cdr import STATUS_NAME

__all__ = ["BEAM", "RECEIVE_MARGIN_S", "chain_parameters", "regress_chain"]

RECEIVE_MARGIN_S = 0.01  # a preview published this long before an odometry had reached the node
BEAM = 32  # readings kept at once: the nearest to the recorded answers, then to the recorder's order


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
    values = {name: value for name, value in controller_parameters(bag).items() if name.startswith("chain.")}
    active = values.pop("chain.active", None) == "enabled"
    try:
        if chain_file is not None:
            from robotino_geom_mpc.params.files import read_parameter_file

            given = read_parameter_file(chain_file, CONTROLLER_NODE)
            return chain_params({k: v for k, v in given.items() if k.startswith("chain.") and k != "chain.active"},
                                where=str(chain_file)), str(chain_file), active
        known = {spec.name for spec in CHAIN_SPECS}
        if values and known <= values.keys():
            return chain_params({k: values[k] for k in known}, where="the controller's recorded parameters"), \
                "the controller's parameters in the recording", active
        stored = run_parameters(bag)[0] or {}
        if known <= stored.keys():
            return chain_params({k: stored[k] for k in known}, where="the run parameters the recorder stored"), \
                "the run parameters the recorder stored", active or stored.get("chain.active") == "enabled"
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
        elif status.message.startswith(ODOMETRY_STATUSES):
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


@dataclass(frozen=True)
class _Tick:
    """One odometry of a search: its place in the recording, publish time, stamp, event, the newest preview the
    node held for sure and the newest the recorder had received (indices).
    """

    index: int
    publish: int
    stamp: int
    newest: int
    recorded_preview: int


_ZERO = "zero"  # a slot whose odometry the loop refused


class _Successors:
    """The readings one reading leads to at one odometry (`_search`), each stepped when the search asks for it.

    In the search's order: the reading still waiting (perhaps no preview yet), then per preview j it may hold (the
    previews after its last one fed in publish order) the step with "now" at either end (the odometry's publish
    time, its answer's), kept if it answers and, at the answer's end, reaches another tick. A refused odometry (the
    node's zero) gives the reading's zero instead of all of them; no answer at all, the reading itself stepped on.
    Every successor's sort key (its worst deviation, how unlikely, its preview) is at least the slot's bound
    (`bound`: the reading's worst deviation and its own likelihood and preview), so that the search can leave
    slots unstepped once the readings it keeps are known.
    """

    def __init__(self, r: _Reading, tick: _Tick, inputs: ControllerInputs, preview_t: list[int],
                 commands: list[tuple[int, np.ndarray]]) -> None:
        self.r, self.tick, self.inputs = r, tick, inputs
        r.deviation = None
        self.waits = r.preview < 0 and tick.newest < 0  # perhaps no preview yet: no answer
        self.commands = len(commands)
        recorded: tuple[int, np.ndarray] = commands[r.command] if r.command < len(commands) else (tick.publish,
                                                                                                    np.zeros(3))
        self.answer_t, self.recorded = recorded
        answers = r.command < len(commands) and self.answer_t > tick.publish  # an answer follows its odometry
        self.slots = [(j, end) for j in range(max(tick.newest, r.preview, 0), bisect_left(preview_t, self.answer_t))
                      for end in (0, 1)] if answers else []
        self.held: _Reading | None = None  # a copy of `r` holding the previews up to its `preview`
        self.refused_from: int | None = None  # the first j whose previews the loop refused (none held)
        self.first: dict[int, list | None] = {}  # j -> the commands after the step at the publish end (None: none)
        self.zero: _Reading | None = None

    def bound(self, slot: int) -> tuple[float, int, int]:
        """The least sort key of the successor of `slot` (-1: the waiting one)."""
        if slot < 0:
            return self.r.count.worst, self.r.unlikely + (self.tick.recorded_preview >= 0), self.r.preview
        j = self.slots[slot][0]
        return self.r.count.worst, self.r.unlikely + abs(j - self.tick.recorded_preview), j

    def waiting(self) -> _Reading:
        waiting = self.r.clone()
        waiting.loop.on_input(self.inputs.odometries[self.tick.index], Now(self.tick.publish, self.tick.publish))
        waiting.unlikely += self.tick.recorded_preview >= 0  # the recorder had one
        return waiting

    def step(self, slot: int) -> _Reading | str | None:
        """The successor of answer `slot` (j, end), `_ZERO` if the loop refused the odometry, None if none."""
        j, end = self.slots[slot]
        if self.refused_from is not None and j >= self.refused_from or end == 1 and self.first.get(j) is None:
            return None  # no preview to hold, or no answer at the publish end: none at the answer's either
        held = self._holding(j)
        if held is None:
            return None
        tick = self.tick
        s = held.clone()
        answer = s.loop.on_input(self.inputs.odometries[tick.index], Now((tick.publish, self.answer_t)[end],
                                                                           tick.publish))
        twists = [o.values for o in answer if isinstance(o, Command)]
        if any(isinstance(o, Zero) for o in answer):
            return _ZERO
        if not twists:
            return None  # dropped (an older stamp) or no step: no answer
        assert s.loop.chain is not None
        commands = s.loop.chain.controller.commands
        if end == 0:
            self.first[j] = commands
        elif commands == self.first[j]:
            return None  # the same tick either way
        s.command = self.r.command + 1
        s.unlikely += abs(j - tick.recorded_preview)  # the recorder's order stands for the node's
        s.count.ticks += 1
        s.deviation = float(np.max(np.abs(np.array(twists[0]) - self.recorded)))
        s.count.compare(tick.stamp, s.deviation)
        return s

    def _holding(self, j: int) -> _Reading | None:
        """A copy of the reading holding the previews up to `j` (None if the loop refused one: the node's zero)."""
        if self.held is None or self.held.preview > j:
            self.held = self.r.clone()
        held, previews = self.held, self.inputs.previews
        for k in range(held.preview + 1, j + 1):
            held.preview = k
            if any(isinstance(o, Zero) for o in held.loop.on_input(self.inputs.preview_events[k],
                                                                  Now(previews[k][0], previews[k][0]))):
                self.refused_from, self.held = j, None
                return None
        return held

    def refused(self) -> _Reading:
        """The reading's zero: noted when the recorded one went out; the reading unstepped if that was not zero."""
        if self.recorded.any():
            return self.r
        z = self.r.clone()
        z.loop.on_input(self.inputs.odometries[self.tick.index], Now(self.answer_t, self.tick.publish))
        z.command += 1
        return z

    def alone(self) -> _Reading:
        """No answer expected (e.g. an older stamp the node drops): the reading takes the odometry all the same. One
        whose next recorded answer went out before this odometry has left it behind: it matches no more (else it
        would stand for the recording wherever the recorded answers stop matching, comparing nothing).
        """
        self.r.loop.on_input(self.inputs.odometries[self.tick.index], Now(self.tick.publish, self.tick.publish))
        if self.r.command < self.commands and self.answer_t <= self.tick.publish:
            self.r.deviation = math.inf
        return self.r


def _search(loop: ControllerLoop, inputs: ControllerInputs, commands: list, tolerance: float) -> Deviations:
    """The bounded search over the unrecorded readings (the module docstring), each a `ControllerLoop`.

    Per odometry the successors of the readings kept are sorted by (worst deviation, how unlikely, preview held),
    those that match the recorded answer kept, one per state, the first `BEAM`. They are stepped best bound first
    (`_Successors.bound`), and the search stops stepping once `BEAM` states of matching successors lie before every
    slot left: the readings kept are those of stepping every slot, at a fraction of the steps while many readings
    match (a robot at rest answers zero whatever the preview and the clock).
    """
    preview_t = [p for p, _ in inputs.previews]
    preview_log = sorted(inputs.preview_log_ns)
    margin = round(RECEIVE_MARGIN_S * 1e9)
    readings = [_Reading(loop)]
    for index, log in enumerate(inputs.odom_log_ns):
        publish, msg = inputs.odom[index]
        tick = _Tick(index, publish, stamp_ns(msg.header.stamp), bisect_right(preview_t, publish - margin) - 1,
                     bisect_left(preview_log, log) - 1)
        readings = _kept([_Successors(r, tick, inputs, preview_t, commands) for r in readings], tolerance)
    return min(readings, key=lambda r: (r.count.worst, -r.count.compared)).count


def _kept(successors: list[_Successors], tolerance: float) -> list[_Reading]:
    """The readings kept of the `successors` of each reading (`_search`)."""
    # per reading in order: its successors so far as (sort key, order, successor, its state); order: the reading's
    # and the slot's (0: the waiting one, or the reading's only successor)
    found: list[list[_Found]] = []
    pending: list[tuple[tuple, tuple[int, int], int, int]] = []  # (bound, order, reading, slot) not yet stepped

    def add(i: int, slot: int, successor: _Reading) -> None:
        """The successor of reading `i`'s `slot` (-1: the waiting one, or its only successor)."""
        key = (successor.count.worst, successor.unlikely, successor.preview)
        found[i].append((key, (i, slot + 1), successor, successor.key()))

    for i, each in enumerate(successors):
        found.append([])
        # the first answer decides for all: a refused odometry is refused whatever the preview (its checks come
        # before the pairing) and at the publish end too if at the answer's; no answer anywhere: the reading alone
        first = 0
        while first < len(each.slots):
            out = each.step(first)
            if out is not None:
                break
            first += 1
        else:
            out = None
        if out == _ZERO:
            add(i, -1, each.refused())
            continue
        if out is None and not each.waits:
            add(i, -1, each.alone())
            continue
        if each.waits:
            pending.append((each.bound(-1), (i, 0), i, -1))
        if isinstance(out, _Reading):
            add(i, first, out)
            pending += [(each.bound(slot), (i, slot + 1), i, slot) for slot in range(first + 1, len(each.slots))]
    heapq.heapify(pending)
    while pending and not _settled(found, pending[0][:2], tolerance):
        _, _, i, slot = heapq.heappop(pending)
        each = successors[i]
        out = each.waiting() if slot < 0 else each.step(slot)
        if out == _ZERO:  # not after an answer (see above): kept for a bug's sake, as stepping every slot would
            found[i] = []
            add(i, -1, each.refused())
            pending = [p for p in pending if p[2] != i]
            heapq.heapify(pending)
        elif isinstance(out, _Reading):
            add(i, slot, out)
    expanded = sorted((item for items in found for item in items), key=lambda item: item[1])
    matching = [item for item in expanded if _matches(item[2], tolerance)]
    if not matching:  # no reading gives the recorded answer: the nearest goes on, its deviation counted
        matching = [min(expanded, key=lambda item: item[2].deviation if item[2].deviation is not None else np.inf)]
    unique: dict[tuple, _Reading] = {}
    for _, _, e, state in sorted(matching, key=lambda item: item[0]):
        unique.setdefault(state, e)
    return list(unique.values())[:BEAM]


_Found = tuple[tuple[float, int, int], tuple[int, int], _Reading, tuple]


def _matches(reading: _Reading, tolerance: float) -> bool:
    return reading.deviation is None or reading.deviation <= tolerance


def _settled(found: list[list[_Found]], frontier: tuple, tolerance: float) -> bool:
    """Whether `BEAM` states of matching successors sort before `frontier` (the least bound and order left)."""
    states = {state for items in found for key, order, e, state in items
              if (key, order) < frontier and _matches(e, tolerance)}
    return len(states) >= BEAM
