"""A second source, in-process: the robot loop driven by one controller while another commands it, the controller
loop fed by one trajectory while another publishes previews (issue 38: cross-talk on a shared ROS domain).

Truths: the same loops fed by the paired source alone (the runs must be equal to the last bit), and the same loops
with the intruder's messages not told apart (they must differ a lot, else the test could not fail).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from robotino_geom_mpc.loop.controller_loop import ControllerLoop, LoopSettings
from robotino_geom_mpc.loop.events import Command, Diagnostic, Now, Preview
from robotino_geom_mpc.loop.robot_loop import PoseNoise, RobotLoop, VoltageDrive
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.offline.lockstep import odometry_event
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import Reference
from robotino_geom_mpc.scenarios import SCENARIOS

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params()
TS = CONTROL.period_s
TS_NS = round(TS * 1e9)
N = CONTROL.horizon
MS = 1_000_000
T0_NS = 1_000 * 10**9
CIRCLE = SCENARIOS["paper-circle"].make_reference()
LEMNISCATE = SCENARIOS["lemniscate"].make_reference()
PAIRED, INTRUDER = b"writer-1", b"writer-2"


def _robot() -> RobotLoop:
    plant = RobotinoPlant(ROBOT)
    return RobotLoop(plant, plant, VoltageDrive(plant), TS, PoseNoise((0.0, 0.0), 0), lease_s=0.5)


def _preview(reference: Reference, t_s: float, stamp_ns: int, source: bytes | None) -> Preview:
    pos, vel, acc, _ = reference.sample(t_s + TS * np.arange(N + 1))
    values: list[float] = []
    for p, v, a in zip(pos.tolist(), vel.tolist(), acc.tolist()):
        values += (p[0], p[1], 0.0, 0.0, math.sin(p[2] / 2), math.cos(p[2] / 2), *v, *a)
    return Preview(stamp_ns, "odom", tuple(values), source)


# the controller: one reference source ------------------------------------------------------------------------
def _controller_run(ticks: int, intruder_from: int | None, tell_apart: bool = True, paired_until: int | None = None
                    ) -> tuple[list[tuple[float, ...]], list[Diagnostic], np.ndarray]:
    """The realtime loop against a plant on an ideal 10 ms grid, fed the paper-circle (the paired trajectory; up
    to tick `paired_until`) and from tick `intruder_from` on a lemniscate started then (the intruder), its
    preview after the paired one's in each tick. Returns the commands, the statuses and the last true pose.
    """
    loop = ControllerLoop(ROBOT, CONTROL, Now(T0_NS, T0_NS), LoopSettings(odom_timeout_s=0.1, reference_timeout_s=0.1))
    robot = _robot()
    commands, statuses = [], []
    held = (0.0, 0.0, 0.0)
    for k in range(ticks):
        stamp = T0_NS + k * TS_NS
        now = Now(stamp, stamp)
        out = []
        if paired_until is None or k < paired_until:
            out += loop.on_preview(_preview(CIRCLE, k * TS, stamp, PAIRED if tell_apart else None), now)
        if intruder_from is not None and k >= intruder_from:
            later = Now(stamp + MS, stamp + MS)
            out += loop.on_preview(_preview(LEMNISCATE, (k - intruder_from) * TS, stamp + MS,
                                            INTRUDER if tell_apart else None), later)
        out += loop.on_odometry(odometry_event(stamp, *robot.measure()), Now(stamp + 2 * MS, stamp + 2 * MS))
        statuses += [o for o in out if isinstance(o, Diagnostic)]
        answer = [o for o in out if isinstance(o, Command)]
        if answer:
            held = answer[-1].values
        commands.append(held)
        robot.drive(held)
    return commands, statuses, np.array(robot.truth()[0])


def test_the_controller_refuses_an_intruders_previews_and_commands_as_with_its_own_trajectory_alone():
    alone, _, pose_alone = _controller_run(300, None)
    paired, statuses, pose = _controller_run(300, 100)
    assert paired == alone  # to the last bit: the intruder touched nothing
    assert np.array_equal(pose, pose_alone)
    last = dict(zip(statuses[-1].keys, statuses[-1].values))
    assert last["refused_second_source"] == "200" and last["rejected"] == "0"
    # not told apart, the intruder's previews are taken: the loop jumps between the references (the failure)
    mixed, mixed_statuses, pose_mixed = _controller_run(300, 100, tell_apart=False)
    assert np.linalg.norm(pose_mixed[:2] - pose_alone[:2]) > 0.01
    assert max(abs(a - b) for m, p in zip(mixed, alone) for a, b in zip(m, p)) > 1.0


def test_the_intruder_takes_the_reference_only_once_the_paired_trajectory_is_stale():
    commands, statuses, pose = _controller_run(1000, 100, paired_until=200)
    alone, _, _ = _controller_run(200, None)
    assert commands[:200] == alone[:200]
    last = dict(zip(statuses[-1].keys, statuses[-1].values))
    # ticks 100..199, and 200..208: the lease (0.1 s) lapses 0.1 s after the paired one's last preview (tick 199)
    assert last["refused_second_source"] == "109"
    # then the lemniscate's reference is blended in from where the robot was and tracked: the pose after the last
    # period (tick 1000) against the lemniscate started at tick 100 and stamped 1 ms late
    reference = LEMNISCATE.sample(np.array([(1000 - 100) * TS - 0.001]))[0][0]
    assert np.hypot(*(pose[:2] - reference[:2])) < 1e-3


# the robot: one controller ----------------------------------------------------------------------------------
def _voltages(k: int, phase: float) -> tuple[float, float, float]:
    return tuple(3.0 * math.sin(0.05 * k + phase + j) for j in range(3))  # type: ignore[return-value]


def _robot_run(ticks: int, intruder: bool, release_at: int | None = None, gate: bool = True
               ) -> tuple[np.ndarray, RobotLoop, list[tuple[float, ...]]]:
    """The robot commanded each period by the paired controller and (`intruder`) after it by another one, steady
    time = the period's start; the command held is the last admitted. `release_at`: ``~/release`` before that
    period. Returns the final state, the robot and the applied commands.
    """
    robot = _robot()
    held: tuple[float, ...] = (0.0, 0.0, 0.0)
    applied = []
    for k in range(ticks):
        now = k * TS_NS
        if release_at == k:
            robot.release()
        senders = [(INTRUDER, _voltages(k, 2.0))] if intruder else []
        senders.insert(0 if release_at is None or k < release_at else 1, (PAIRED, _voltages(k, 0.0)))
        for source, values in senders:
            if not gate or robot.admit(source, now + MS):
                held = robot.check_command(values)[0]
        applied.append(held)
        robot.run(held, TS)
    return robot.plant.state.copy(), robot, applied


def test_the_robot_never_applies_the_intruders_commands():
    alone, _, applied_alone = _robot_run(200, intruder=False)
    state, robot, applied = _robot_run(200, intruder=True)
    assert applied == applied_alone and np.array_equal(state, alone)
    assert robot.counts["refused_second_source"] == 200 and robot.pairing.refused == {INTRUDER: 200}
    _, _, applied_open = _robot_run(200, intruder=True, gate=False)  # no pairing: the last sender's applied
    assert applied_open != applied_alone


def test_a_release_hands_the_robot_to_the_next_controller_that_commands():
    _, robot, applied = _robot_run(200, intruder=True, release_at=100)
    # from the release on the intruder commands first each period and takes the lease; the paired one is refused
    assert applied[:100] == [tuple(_voltages(k, 0.0)) for k in range(100)]
    assert applied[100:] == [tuple(_voltages(k, 2.0)) for k in range(100, 200)]
    assert robot.pairing.holder == INTRUDER and robot.pairing.refused == {INTRUDER: 100, PAIRED: 100}
