"""What the loops take and answer: plain frozen dataclasses, stamps and times in integer nanoseconds.

A loop method (`loop.controller_loop.ControllerLoop`, `loop.robot_loop.RobotLoop`) takes one input and the
time (`Now`), decides, and returns a list of `Output`: the node publishes them, the replay compares them, the
offline loop applies them. Inputs carry their stamps and already-decoded floats (decoding CDR stays in the
adapters); an input that could not be decoded is an `Undecodable` (a refusal the loop counts and answers). An
in-process driver (the offline runs) hands its odometry and previews over with the yaw as it is
(`PlanarOdometry`, `PlanarPreview`) instead of the messages' quaternions.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple, Union

import numpy as np

from robotino_geom_mpc.network.plan import CommandPlan

__all__ = ["AppliedReport", "Command", "Diagnostic", "EnabledChanged", "Level", "Log", "Now", "Odometry", "Output",
           "PlanOut", "PlanarOdometry", "PlanarPreview", "PredictedPath", "Preview", "Resend", "Undecodable", "Waiting",
           "Zero"]


class Level(IntEnum):
    """Severity of a diagnostic or log line (diagnostic_msgs/DiagnosticStatus levels; DEBUG/INFO for logs)."""

    OK = 0
    WARN = 1
    ERROR = 2
    INFO = 10


@dataclass(frozen=True)
class Now:
    """The time handed to a loop with each input.

    Attributes
    ----------
    clock_ns
        The node clock (ROS time; simulated time under ``use_sim_time``): realtime input stamps are checked
        against it, and the chain controller steps at it.
    watch_ns
        The watchdog's clock: steady time, or the node clock under ``use_sim_time`` (a slow simulation is slow,
        not stale). Arrival ages are measured on it.
    """

    clock_ns: int
    watch_ns: int


# inputs -------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Odometry:
    """An odometry: its stamp and (x, y, q_x, q_y, q_z, q_w, v_x, v_y, omega): pose in odom, twist in base_link."""

    stamp_ns: int
    values: tuple[float, ...]


@dataclass(frozen=True)
class PlanarOdometry:
    """An odometry of an in-process robot (the offline runs): its stamp, the pose (x, y, theta) in odom with theta
    continuous, and the base_link twist (v_x, v_y, omega). The yaw an `Odometry` carries as a quaternion, without
    it: nothing to decode, unwrap or check but finiteness (building a quaternion only for the loop to take it
    apart would be a conversion, not protocol).
    """

    stamp_ns: int
    pose: tuple[float, float, float]
    twist: tuple[float, float, float]


@dataclass(frozen=True)
class Preview:
    """A reference preview: its stamp, frame and per point (x, y, q_x, q_y, q_z, q_w, velocity and acceleration
    (x, y, theta)), flat (`loop.inputs.POINT_SIZE` values a point, any number of points: the loop checks); its
    `source` (the publisher, `loop.source_pairing`; None: not told, every preview is the paired source's).
    """

    stamp_ns: int
    frame: str
    values: tuple[float, ...]
    source: bytes | None = None


@dataclass(frozen=True)
class PlanarPreview:
    """A reference preview of an in-process reference (the offline runs): its stamp, frame and per point (x, y,
    theta, their velocities, their accelerations), flat (`loop.inputs.PLANAR_POINT_SIZE` values a point), theta
    continuous: a `Preview` without the quaternions.
    """

    stamp_ns: int
    frame: str
    values: tuple[float, ...]


@dataclass(frozen=True)
class Undecodable:
    """An input that could not be read (undecodable bytes, a stamp that is no time, a malformed report).

    `topic` is ``odom``, ``reference_preview`` or ``command_applied``; `stamp_ns` its stamp if it was read.
    """

    topic: str
    stamp_ns: int | None
    reason: str
    message: str


class AppliedReport(NamedTuple):
    """One ``command_applied`` event: `values` None = receipt of plan `basis_s` at `time_s` (`taken` by the
    buffer or not); else the period starting at `time_s` got `values` (entry `entry_index` of plan `basis_s`; basis
    None: no plan, zero).
    """

    time_s: float
    basis_s: float | None
    entry_index: int
    values: tuple[float, float, float] | None
    taken: bool = True


# outputs ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Command:
    """The answer to the odometry of `stamp_ns`: wheel voltages [V] or a base_link twist (v_x, v_y, theta')."""

    stamp_ns: int
    values: tuple[float, float, float]


@dataclass(frozen=True)
class Zero:
    """Zero volts (a zero twist) sent outside the answers: a refused input, the watchdog, the stop."""

    reason: str


@dataclass(frozen=True)
class Resend:
    """Lockstep: the plant resent the tick `stamp_ns`: send the answers still held, if their readers have matched."""

    stamp_ns: int


@dataclass(frozen=True)
class PlanOut:
    """The plan made for the odometry of `stamp_ns` (plans over a link)."""

    stamp_ns: int
    plan: CommandPlan


@dataclass(frozen=True)
class Diagnostic:
    """The controller's status: header stamp [ns] (an input's stamp, else the clock), level, message, key/values."""

    stamp_ns: int
    level: Level
    message: str
    keys: tuple[str, ...]
    values: tuple[str, ...]

    def as_dict(self) -> dict[str, str]:
        """The key/values as a dict."""
        return dict(zip(self.keys, self.values))


@dataclass(frozen=True)
class PredictedPath:
    """The MPCs' predicted poses y(k+1) .. y(k+N) (shape (N, 3)) of the tick `stamp_ns`, pose j at `stamps_ns[j-1]`
    (= `stamp_ns` + j Ts).
    """

    stamp_ns: int
    stamps_ns: tuple[int, ...]
    poses: np.ndarray = field(compare=False)


@dataclass(frozen=True)
class Log:
    """A log line; `throttle_s` > 0: at most once per that time per `key` (the adapter throttles)."""

    level: Level
    text: str
    key: str
    throttle_s: float = 0.0


@dataclass(frozen=True)
class Waiting:
    """What the controller has been waiting for (no input for a timeout), said by the watchdog; the adapter names
    the topic and its publishers (throttled, every 5 s).

    `what`: ``preview_of_stamp`` (the odometry of `stamp_ns` waits for the preview of that stamp), ``odometry``
    (none since the start, `since_start`, or since the last one) or ``preview`` (none yet).
    """

    what: str
    waited_s: float
    stamp_ns: int | None = None
    since_start: bool = False


@dataclass(frozen=True)
class EnabledChanged:
    """The controller was enabled or disabled (``controller_enabled`` is published)."""

    enabled: bool


Output = Union[Command, Zero, Resend, PlanOut, Diagnostic, PredictedPath, Log, Waiting, EnabledChanged]
