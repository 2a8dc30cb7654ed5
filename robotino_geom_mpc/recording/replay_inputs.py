"""What every replay of a recording (`regress`: voltages and cmd_vel, `regress_plans`, `regress_chain`) reads and
how it hands it to a fresh `loop.controller_loop.ControllerLoop`: written once here, the pairing of each recorded
answer with its input being the one thing each mode does its own way.

`ControllerInputs` holds the controller's recorded inputs in publish order, decoded once into the loop's events
(`ros.decode.odometry_input`, `preview_input`): the ``odom`` and ``reference_preview`` messages with their publish
times (and the recorder's receive times, which the chain's search reads), each preview stamp's first message, and
what the controller's tracking statuses say per odometry stamp (the preview it used, ``preview_stamp_ns``; the
robot's reports it had received, ``reports_received``). It builds the loop the node was (`loop`), and hands the
previews on in publish order, each once, up to an index (`PreviewFeed`). `NodeClock` gives each odometry the
node's clock as it took it and replays the watchdog's stops where they came. `Deviations` counts the ticks
answered and the answers compared, and keeps the largest deviation and its stamp.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop, LoopSettings
from robotino_geom_mpc.loop.events import Now, Odometry, Output, Preview, Undecodable
from robotino_geom_mpc.params.specs import LOOP_SPECS, ControlParams, RobotinoParams
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.topics import CONTROLLER_NODE, by_publish_time, controller_diagnostics, \
    controller_parameters, find_topic, run_parameters, stamp_ns
from robotino_geom_mpc.ros.controller_cdr import STATUS_NAME
from robotino_geom_mpc.ros.decode import odometry_input, preview_input

__all__ = ["ODOMETRY_STATUSES", "WATCHDOG_STALE_NS", "ControllerInputs", "Deviations", "NodeClock", "PreviewFeed",
           "diagnostics", "loop_settings"]

WATCHDOG_STALE_NS = 10**12  # a recorded watchdog stop replayed on a watchdog clock this far on: stale for sure
# the controller's statuses of an odometry it took (stamped with its stamp): a step, or its refusal
ODOMETRY_STATUSES = ("tracking", "chain", "disabled", "refused odom", "dropped odom", "refused input")


def diagnostics(bag: BagReader) -> list[tuple[int, Any]]:
    """(publish time, DiagnosticArray) of the recording's ``diagnostics``, in publish order ([] without)."""
    return by_publish_time(bag, find_topic(bag, "diagnostics", "diagnostic_msgs/msg/DiagnosticArray", False))


@dataclass(frozen=True)
class ControllerInputs:
    """The controller's recorded inputs (module docstring); `read` builds it from a recording.

    Attributes
    ----------
    odom, previews
        (publish time [ns], message) of ``odom`` and ``reference_preview``, in publish order.
    odometries, preview_events
        The same messages as the loop's input events.
    odom_log_ns, preview_log_ns
        The recorder's receive times [ns], the publish times' order (`read` with ``log_times``; else empty).
    first_of
        Preview stamp [ns] -> index of its first message.
    used, received
        Odometry stamp [ns] -> the preview stamp its status names, the reports it had received.
    preview_clock
        Odometry stamp [ns] -> the node clock when it took the newest preview it had (its status's
        ``preview_clock_ns``; recordings made before the statuses carried it: none).
    enabled
        Odometry stamp [ns] -> whether the controller was enabled at it: its status ``disabled`` (false) or a
        step's (``tracking``, ``chain``: true); `follow_enable` hands that to a replay.
    settings
        The controller loop's settings the node ran with (`loop_settings`).
    """

    path: str
    odom: list[tuple[int, Any]]
    previews: list[tuple[int, Any]]
    odometries: list[Odometry | Undecodable]
    preview_events: list[Preview | Undecodable]
    first_of: dict[int, int]
    used: dict[int, int]
    received: dict[int, int]
    settings: LoopSettings = LoopSettings()
    preview_clock: dict[int, int] = field(default_factory=dict)
    enabled: dict[int, bool] = field(default_factory=dict)
    odom_log_ns: list[int] = field(default_factory=list)
    preview_log_ns: list[int] = field(default_factory=list)

    @classmethod
    def read(cls, bag: BagReader, diags: list[tuple[int, Any]], log_times: bool = False) -> ControllerInputs:
        """The inputs of `bag` (`diags`: its `diagnostics`); BagError without odometry or previews' topic."""
        odom_topic = find_topic(bag, "odom", "nav_msgs/msg/Odometry")
        preview_topic = find_topic(bag, "reference_preview", "trajectory_msgs/msg/MultiDOFJointTrajectory")
        odom, previews = by_publish_time(bag, odom_topic), by_publish_time(bag, preview_topic)
        if not odom:
            raise BagError(f"{bag.path}: no odometry tick in the recording")
        first_of: dict[int, int] = {}
        for j, (_, msg) in enumerate(previews):
            first_of.setdefault(stamp_ns(msg.header.stamp), j)
        used: dict[int, int] = {}
        received: dict[int, int] = {}
        preview_clock: dict[int, int] = {}
        enabled: dict[int, bool] = {}
        for _, msg in diags:
            for status in msg.status:
                if status.name == STATUS_NAME and status.message in ("disabled", "tracking", "chain"):
                    enabled.setdefault(stamp_ns(msg.header.stamp), status.message != "disabled")
            values = controller_diagnostics(msg)
            if values is None:
                continue
            stamp = stamp_ns(msg.header.stamp)
            if values.get("preview_stamp_ns", "").isdigit():
                used.setdefault(stamp, int(values["preview_stamp_ns"]))
            if values.get("reports_received", "").isdigit():
                received.setdefault(stamp, int(values["reports_received"]))
            if values.get("preview_clock_ns", "").isdigit():
                preview_clock.setdefault(stamp, int(values["preview_clock_ns"]))
        return cls(str(bag.path), odom, previews, [odometry_input(msg) for _, msg in odom],
                   [preview_input(msg) for _, msg in previews], first_of, used, received,
                   loop_settings(bag, odom_topic), preview_clock, enabled,
                   _log_times(bag, odom_topic) if log_times else [],
                   _log_times(bag, preview_topic) if log_times else [])

    @property
    def first_stamp(self) -> int:
        """The first odometry's stamp [ns] (the origin of the reported times)."""
        return stamp_ns(self.odom[0][1].header.stamp)

    def loop(self, robot: RobotinoParams, control: ControlParams, **mode: Any) -> ControllerLoop:
        """A fresh loop as the node was: started at the first odometry's publish time, in the previews' frame,
        quiet (only the commands are compared); `mode`: the loop's keywords (lockstep, interface, plans, chain).
        """
        start = self.odom[0][0]
        frame = self.previews[0][1].header.frame_id if self.previews else "odom"
        return ControllerLoop(robot, control, Now(start, start), self.settings, odom_frame=frame, listeners=QUIET,
                              **mode)

    def follow_enable(self, loop: ControllerLoop, stamp: int, now: Now) -> None:
        """Switch `loop` to the enabled state the node had at the odometry of `stamp` (``~/enable`` between two
        ticks: the next status says it; a tick without a status leaves the loop as it is).
        """
        enabled = self.enabled.get(stamp)
        if enabled is not None and enabled != loop.enabled:
            loop.on_enable(enabled, now)

    def seconds(self, stamp: int | None) -> float | None:
        """`stamp` [ns] as seconds after the first odometry's stamp (None stays None)."""
        return None if stamp is None else (stamp - self.first_stamp) * 1e-9


def loop_settings(bag: BagReader, odom_topic: str) -> LoopSettings:
    """The controller loop's settings (`params.specs.LOOP_SPECS`) the node of `odom_topic`'s namespace ran with: its
    parameter events in the recording over the values the recorder stored (`run` and the launch give it those
    they give the controller, e.g. a realtime fleet's ``reference_timeout_s``) over the defaults.
    """
    names = {spec.name for spec in LOOP_SPECS}
    values = {name: value for name, value in (run_parameters(bag)[0] or {}).items()
              if name in names and value is not None}
    recorded = controller_parameters(bag, odom_topic.rsplit("/", 1)[0] + "/" + CONTROLLER_NODE)
    values.update((name, value) for name, value in recorded.items() if name in names)
    try:
        return LoopSettings.of(values)
    except (TypeError, ValueError):
        raise BagError(f"{bag.path}: the controller's loop settings in the recording are not numbers: {values}") \
            from None


def _log_times(bag: BagReader, topic: str) -> list[int]:
    """The recorder's receive times of `topic`'s messages, in the order of their publish times."""
    return [log for _, log in sorted((m.publish_time_ns, m.log_time_ns) for m in bag.messages([topic]))]


class PreviewFeed:
    """Hands a loop the recorded previews in publish order, each once (`up_to`), or one by its index (`give`)."""

    def __init__(self, loop: ControllerLoop, inputs: ControllerInputs) -> None:
        self.loop, self.inputs = loop, inputs
        self.fed = -1  # index of the last preview handed on

    def up_to(self, last: int, clock: int | None = None,
              skip: frozenset[int] | set[int] = frozenset()) -> Iterator[tuple[int, list[Output]]]:
        """(index, the loop's outputs) of each preview after those fed up to index `last` but those in `skip`, each
        at its publish time on the watch clock and at `clock` on the node's (None: its publish time).
        """
        for j in range(self.fed + 1, last + 1):
            self.fed = j
            if j not in skip:
                yield j, self.give(j, clock)

    def give(self, j: int, clock: int | None = None) -> list[Output]:
        """The loop's outputs to preview `j` (lockstep: a tick's own, by stamp), at `clock` as in `up_to`."""
        publish = self.inputs.previews[j][0]
        return self.loop.on_input(self.inputs.preview_events[j], Now(publish, publish if clock is None else clock))

    def feed(self, last: int, clock: int | None = None) -> None:
        """`up_to` whose outputs nobody reads."""
        for _ in self.up_to(last, clock):
            pass

    def feed_used(self, last: int, taken_ns: int | None) -> None:
        """`feed` up to the preview a realtime tick used, index `last`, that one at `taken_ns` on both clocks: when
        the node took it (its status's ``preview_clock_ns``: behind, later than its publication, and its age at
        the tick counts from then); None: at its publication.
        """
        if taken_ns is None or last <= self.fed:
            self.feed(last)
            return
        self.feed(last - 1)
        self.fed = last
        self.loop.on_input(self.inputs.preview_events[last], Now(taken_ns, taken_ns))


@dataclass
class NodeClock:
    """The controller's clock in its statuses: when each watchdog stop fired (the status's stamp) and, per odometry
    it took (a status stamped with the odometry's stamp), its clock then (the status's ``clock_ns``; recordings
    made before the statuses carried it: the status's publication, a little later).
    """

    stops: deque[int]
    taken: dict[int, int]

    @classmethod
    def read(cls, diags: list[tuple[int, Any]]) -> NodeClock:
        stops: deque[int] = deque()
        taken: dict[int, int] = {}
        for publish, msg in diags:
            stamp = stamp_ns(msg.header.stamp)
            for status in msg.status:
                if status.name != STATUS_NAME:
                    continue
                if status.message.startswith("watchdog"):
                    stops.append(stamp)
                elif status.message.startswith(ODOMETRY_STATUSES) and stamp not in taken:
                    clock = next((kv.value for kv in status.values if kv.key == "clock_ns"), "")
                    taken[stamp] = int(clock) if clock.isdigit() else publish
        return cls(stops, taken)

    def took(self, stamp: int) -> bool:
        """Whether the node took the realtime odometry of `stamp`: one with a status, or any in a recording without
        statuses. Its reader keeps the newest odometry only (`ros.qos.LATEST_QOS`): one that a newer replaced
        before the node took it was never answered, and the replay skips it as the node did (the silent ticks
        the node took, with no preview or a stale one, change no state a later answer reads).
        """
        return not self.taken or stamp in self.taken

    def take(self, loop: ControllerLoop, stamp: int, publish: int) -> Now:
        """The time the node took the odometry of `stamp` (published at `publish`: without a status, that), after
        the watchdog stops that fired before it (on `loop`: stale by then for sure; the node decided on its steady
        clock).
        """
        clock = self.taken.get(stamp, publish)
        while self.stops and self.stops[0] < clock:
            fired = self.stops.popleft()
            loop.on_watchdog(Now(fired, fired + WATCHDOG_STALE_NS))
        return Now(clock, clock)


@dataclass
class Deviations:
    """The replay's count: ticks answered, answers compared, the largest deviation and the stamp [ns] of its tick."""

    ticks: int = 0
    compared: int = 0
    worst: float = 0.0
    worst_stamp: int | None = None

    def compare(self, stamp: int, deviation: float) -> None:
        """One compared answer of the tick of `stamp`."""
        self.compared += 1
        if self.worst_stamp is None or deviation > self.worst:
            self.worst, self.worst_stamp = deviation, stamp
