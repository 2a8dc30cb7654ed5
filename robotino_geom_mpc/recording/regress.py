"""Replay regression: a recording's odometry and reference previews through a fresh controller loop.

A fresh `loop.controller_loop.ControllerLoop` (the node's tick protocol), built from the run parameters the
recording stores (or a parameter file), is given what the controller node got, in the recorded order with the
recorded times (each message's publish time as the clock; an odometry the node published a status of at its clock
then, the status's ``clock_ns``, in older recordings the status's publication): every ``odom`` message once (a
realtime one the node published no status of was never taken: skipped) and the ``reference_preview`` messages the
node had by then -- lockstep: the preview of the same stamp (the loop pairs them); realtime: the previews up to the
one the node's diagnostics name for the tick (``preview_stamp_ns``; that one at the clock the node took it,
``preview_clock_ns``, when the status names it), else those published before the next odometry (the ticks before the
first preview the diagnostics name are not answered: the node had no preview yet). The loop answers as the node did:
the preview moved to the tick's stamp, the step interval, the bumpless (re)starts, zero on a refused input. Its
commands are compared with the recorded ``wheel_voltages`` answer of the tick (paired through the controller's
``diagnostics``, stamped with the tick, see `report`). Deterministic code on identical inputs gives identical
floats, so the tolerance is 1e-12 V. A cmd_vel run (its controller sent twists on ``cmd_vel``, no
``wheel_voltages``) is compared the same way on the twist the node sends (v_x, v_y [m/s], theta' [rad/s] in
base_link; zero where the node refused the input), with the same tolerance in those units. Runs with plans:
`regress_plans`; chain runs: `regress_chain`; what all of them read from a recording and how they hand it to the
loop: `replay_inputs`.

The controller carries state from tick to tick (u(k-1) of the Delta-u form, the pose estimate), so the replay
needs every tick's inputs. In a lockstep recording (its first tick has a preview of the same stamp; the ticks are
one control period apart) it stops at the first tick whose odometry (the next stamp is more than 1.5 periods on)
or preview is missing from the recording, and says so (`RegressionResult.gap_at_s`). A recorder that fell behind
a fast lockstep loop can have lost samples; the ticks before the gap are still compared.

The node's watchdog stops (its ``watchdog: ...`` statuses) are replayed where they came on the node's clock (the
status's stamp): before the first odometry the node took later. ``~/enable`` is replayed from the tick statuses:
before an odometry whose status is ``disabled`` the loop is disabled, before one with a step's status enabled
again (`replay_inputs.ControllerInputs.follow_enable`), so a disabled tick answers zero (with plans a plan of
zeros) and the next enabled one restarts bumplessly, as the node did. The loop's own settings (timeouts, tolerances,
blend limits) are the node's (`replay_inputs.loop_settings`: its parameter events in the recording, else the values
the recorder stored, else the defaults). Limits: a parameter change during the run (the node rebuilds its
controller) is not replayed; such a recording shows a deviation from that tick on.
"""

from __future__ import annotations

import math
import os
from bisect import bisect_left
from dataclasses import dataclass
from typing import Any

import numpy as np

from robotino_geom_mpc.loop.events import Command, Zero
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.regress_chain import chain_parameters, regress_chain
from robotino_geom_mpc.recording.regress_plans import regress_plans
from robotino_geom_mpc.recording.replay_inputs import ControllerInputs, Deviations, NodeClock, PreviewFeed, diagnostics
from robotino_geom_mpc.recording.report import resolve_parameters
from robotino_geom_mpc.recording.topics import by_publish_time, controller_diagnostics, find_topic, plan_topic, stamp_ns
from robotino_geom_mpc.scenarios import SCENARIOS

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
    chain mode publishes none) is replayed by `regress_chain`. The controller is the recording's robot (or
    `params_file`'s) as `run` gave it to the node: under the stored scenario's model mismatch, if any.

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
    robot, control, scenario, _ = resolve_parameters(bag, params_file)
    if scenario in SCENARIOS:  # `run` gave the controller the scenario's model (`scenarios.node_parameters`)
        robot = SCENARIOS[scenario].controller_model(robot)
    diags = diagnostics(bag)
    if plan_topic(bag) is not None:  # a run with plans (over a link): its plans recomputed (`regress_plans`)
        inputs = ControllerInputs.read(bag, diags)
        count, topic = regress_plans(bag, inputs, diags, robot, control)
        return _result(inputs, count, tolerance_v, command=topic)
    command = find_topic(bag, "wheel_voltages", "std_msgs/msg/Float64MultiArray", False)
    twists = command is None  # a cmd_vel run: the controller's twists
    if twists and find_topic(bag, "cmd_vel", "geometry_msgs/msg/Twist", False) is None:
        raise BagError(f"{bag.path}: no 'wheel_voltages' (std_msgs/msg/Float64MultiArray) nor 'cmd_vel' "
                       "(geometry_msgs/msg/Twist) topic in the recording: no controller command to compare")
    voltages = by_publish_time(bag, command or find_topic(bag, "cmd_vel", "geometry_msgs/msg/Twist"))
    if twists and (chain_file is not None or chain_parameters(bag)[2]
                   or not any(controller_diagnostics(msg) is not None for _, msg in diags)):
        inputs = ControllerInputs.read(bag, diags, log_times=True)
        count, source = regress_chain(bag, inputs, voltages, diags, robot, control, tolerance_v, chain_file)
        return _result(inputs, count, tolerance_v, command="cmd_vel", chain_source=source)
    inputs = ControllerInputs.read(bag, diags)
    count, gap = _replay(inputs, voltages, diags, robot, control, twists)
    return _result(inputs, count, tolerance_v, gap_at_s=inputs.seconds(None if gap is None else gap[0]),
                   gap=None if gap is None else gap[1], command="cmd_vel" if twists else "wheel_voltages")


def _result(inputs: ControllerInputs, count: Deviations, tolerance_v: float, **outcome: Any) -> RegressionResult:
    return RegressionResult(count.ticks, count.compared, count.worst, inputs.seconds(count.worst_stamp),
                            float(tolerance_v), **outcome)


def _replay(inputs: ControllerInputs, commands: list[tuple[int, Any]], diags: list[tuple[int, Any]],
            robot: RobotinoParams, control: ControlParams, twists: bool) -> tuple[Deviations, tuple[int, str] | None]:
    """The replay of a run without plans nor the chain (the module docstring): the count, and the first tick
    (stamp, the missing topic) whose input a lockstep recording lacks, or None.
    """
    volt_t = [p for p, _ in commands]
    answers: dict[int, np.ndarray] = {}  # tick stamp -> recorded voltages
    for publish, msg in diags:
        i = bisect_left(volt_t, publish) - 1
        if i >= 0 and controller_diagnostics(msg) is not None:
            answers.setdefault(stamp_ns(msg.header.stamp), _command_values(commands[i][1], twists))
    node = NodeClock.read(diags)  # its watchdog stops (realtime: zero, the stamps and the preview forgotten)
    odom, by_stamp, used = inputs.odom, inputs.first_of, inputs.used
    prev_t = [p for p, _ in inputs.previews]
    # the first tick has a preview of its own stamp; realtime stamps follow the plant's timer, late or not,
    # so only a lockstep recording is tested for gaps
    lockstep = inputs.first_stamp in by_stamp
    replay = inputs.loop(robot, control, lockstep=lockstep, interface="cmd_vel" if twists else "voltages")
    previews = PreviewFeed(replay, inputs)
    seen: set[int] = set()
    count = Deviations()
    previous = gap = None
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
        if not lockstep and not node.took(stamp):
            continue  # replaced by a newer one in the node's reader before it took it
        now = node.take(replay, stamp, publish)
        # the previews the node had by this odometry: lockstep that of its stamp; realtime up to the one its
        # diagnostics name, else those published before its answer (none before the first one named)
        if lockstep:
            previews.give(by_stamp[stamp])
        elif stamp in used:
            previews.feed_used(by_stamp.get(used[stamp], previews.fed), inputs.preview_clock.get(stamp))
        elif not used or count.ticks > 0:
            answer_publish = odom[index + 1][0] if index + 1 < len(odom) else publish + 10**9
            previews.feed(bisect_left(prev_t, answer_publish) - 1)
        inputs.follow_enable(replay, stamp, now)
        out = replay.on_input(inputs.odometries[index], now)
        expected = next((o.values for o in out if isinstance(o, Command) and o.stamp_ns == stamp), None)
        if expected is None:
            if not any(isinstance(o, Zero) for o in out):
                continue  # no answer: the node had no preview yet, or dropped the odometry
            expected = (0.0, 0.0, 0.0)  # refused: zero output
        count.ticks += 1
        recorded = answers.get(stamp)
        if recorded is not None and recorded.shape == (3,):
            count.compare(stamp, float(np.max(np.abs(np.asarray(expected) - recorded))))
    if count.ticks == 0:
        raise BagError(f"{inputs.path}: no odometry tick in the recording")
    return count, gap


def _command_values(msg: Any, twist: bool) -> np.ndarray:
    """The recorded command: wheel voltages, or a Twist's (linear.x, linear.y, angular.z)."""
    if twist:
        return np.array((msg.linear.x, msg.linear.y, msg.angular.z))
    return np.array(msg.data)
