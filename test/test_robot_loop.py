"""The robot side of the loop in-process, with a hand-driven clock: the link's queue (loss, reordering, duplicates),
the answers the lockstep controller owes, the held command and its watchdog, the plan follower (exhaustion,
reports, a plan taken within a period), the command buffer's dispatcher, and RobotLoop's period against the
plant stepped by hand.
"""

import math

import numpy as np
import pytest

from robotino_geom_mpc.loop.command_link import CommandLink
from robotino_geom_mpc.loop.events import AppliedReport
from robotino_geom_mpc.loop.link_queue import LinkQueue, RobotLink
from robotino_geom_mpc.loop.plan_follower import ZERO, PlanDispatcher, PlanFollower
from robotino_geom_mpc.loop.robot_loop import PoseNoise, RealtimeGrid, RobotLoop, TwistDrive, VoltageDrive
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WheelSpeedLoop
from robotino_geom_mpc.network.link import Link, LinkParams
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params(None)
TS = 0.01


def _plan(basis: float, entries: int, first: float | None = None, value: float = 1.0) -> CommandPlan:
    start = basis if first is None else first
    return CommandPlan(basis, tuple(start + i * TS for i in range(entries)),
                       tuple((value + i, -value - i, 0.5 * i) for i in range(entries)), TS)


# the link's queue ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("params", [LinkParams(0.02, 0.03), LinkParams(0.01, 0.0, 0.3, 3.0),
                                    LinkParams(0.0, 0.02, 0.0, 1.0, 0.4)])
def test_the_queue_hands_out_each_delivery_of_the_link_in_time_then_sending_order(params):
    """The deliveries a second `Link` of the same seed draws, sorted by (time, send index), cut at each tick."""
    queue: LinkQueue[int] = LinkQueue(params, seed=5)
    twin = Link(params, 5)
    expected = []
    got = []
    for k in range(400):
        t = k * TS
        copies = queue.send(t, k)
        times = twin.transmit(t)
        assert copies == len(times)
        expected += [(d, k) for d in times]
        got += [(t, packet) for packet in queue.due(t)]
    got += [(math.inf, packet) for packet in queue.due(math.inf)]
    expected.sort()
    assert [packet for _, packet in got] == [packet for _, packet in expected]
    for (tick, packet), (delivery, _) in zip(got, expected):
        assert delivery <= tick + 1e-6 and (tick == math.inf or delivery > tick - TS + 1e-6)  # at the first tick after
    sent = [p for _, p in expected]
    if params.loss:
        assert len(set(range(400)) - set(sent)) > 50  # lost ones never come
    if params.duplicate:
        assert len(sent) - len(set(sent)) > 50  # duplicates come twice
    if params.jitter_s > TS:
        assert any(b < a for a, b in zip(sent, sent[1:]))  # reordered


def test_a_perfect_queue_delivers_at_once_in_sending_order():
    queue: LinkQueue[str] = LinkQueue(None, seed=0)
    assert not queue.enabled
    for name in "abc":
        queue.send(1.0, name)
    assert queue.due(1.0) == ["a", "b", "c"] and queue.due(2.0) == []


def test_the_lockstep_controller_answers_only_odometries_newer_than_every_one_before():
    link = RobotLink(None, None, 0)
    assert link.answers_due([3, 1, 3, 5]) == 2  # 3, then 5 (1 came reordered, the second 3 twice)
    assert link.answers_due([4, 6]) == 1  # 4 is older than 5 delivered before
    assert link.answers_due([]) == 0


# the held command and its watchdog -----------------------------------------------------------------------------
def test_a_plain_command_is_held_until_it_is_older_than_the_timeout_then_zero_counted():
    robot = CommandLink(None, None, 0, command_timeout_s=0.1)
    assert robot.period_command(0.0) == ZERO and robot.timeouts == 0  # none held yet: zero, no timeout
    robot.send_down(0.0, (1.0, 2.0, 3.0))
    robot.take_due(0.0)
    assert robot.period_command(0.1) == (1.0, 2.0, 3.0)  # exactly the timeout: still held
    assert robot.period_command(0.11) == ZERO and robot.timeouts == 1


def test_over_a_delayed_link_the_command_arrives_at_the_first_tick_after_its_delivery():
    robot = CommandLink(None, LinkParams(0.025), 0)
    robot.send_down(0.0, (1.0, 0.0, 0.0))
    for k in (0, 1, 2):
        robot.take_due(k * TS)
        assert robot.period_command(k * TS) == ZERO
    robot.take_due(3 * TS)
    assert robot.period_command(3 * TS) == (1.0, 0.0, 0.0) and robot.held == (3 * TS, (1.0, 0.0, 0.0))


def test_the_robot_packet_carries_the_reports_since_the_last_one():
    follower = PlanFollower(TS)
    robot = CommandLink(None, None, 0, follower)
    robot.send_down(0.0, _plan(0.0, 2))
    robot.take_due(0.0)
    robot.period_command(0.0)
    (packet,) = robot.send_up(TS, ("odom", robot.pop_reports()))
    _, reports = packet
    assert reports == [AppliedReport(0.0, 0.0, -1, None, True), AppliedReport(0.0, 0.0, 0, (1.0, -1.0, 0.0))]
    assert robot.pop_reports() == []


# the plans -------------------------------------------------------------------------------------------------------
def test_plans_exhaustion_reports_and_refusals():
    follower = PlanFollower(TS)
    assert follower.take(_plan(0.0, 2), 0.0) is None
    assert follower.command_at(0.0)[1] == (1.0, -1.0, 0.0)
    assert follower.command_at(TS)[1] == (2.0, -2.0, 0.5)
    applied, values = follower.command_at(2 * TS)  # used up
    assert applied is None and values == ZERO and follower.counts["exhausted_periods"] == 1
    assert follower.take(_plan(0.0, 2), 2 * TS) == "duplicate"
    assert follower.take(_plan(0.0, 0), 2 * TS) == "length"
    follower.refuse("stamp")  # a message that could not be read at all
    assert follower.counts == {"refused_plans": 2, "ignored_plans": 1, "exhausted_periods": 1}
    assert follower.refused == {"length": 1, "stamp": 1}
    assert follower.pop_reports() == [
        AppliedReport(0.0, 0.0, -1, None, True), AppliedReport(0.0, 0.0, 0, (1.0, -1.0, 0.0)),
        AppliedReport(TS, 0.0, 1, (2.0, -2.0, 0.5)), AppliedReport(2 * TS, None, -1, ZERO),
        AppliedReport(2 * TS, 0.0, -1, None, False), AppliedReport(2 * TS, 0.0, -1, None, False)]


def test_a_plan_taken_within_a_period_acts_from_the_next_one_and_unchanged_commands_are_reported_once():
    follower = PlanFollower(TS)
    follower.take(_plan(0.0, 4), 0.0)
    assert follower.period_command(0.0) == (1.0, -1.0, 0.0)
    follower.take(_plan(0.005, 4, first=TS, value=10.0), 0.005)  # mid-period: the period keeps its command
    assert follower.period_command(0.0) == (1.0, -1.0, 0.0)
    assert follower.period_command(TS) == (10.0, -10.0, 0.0)
    assert [r.entry_index for r in follower.pop_reports() if r.values is not None] == [0, 0]


def test_the_dispatcher_sends_each_entry_once_zero_once_a_period_when_used_up_then_idles():
    follower = PlanFollower(TS)
    dispatcher = PlanDispatcher(follower, idle_after_s=0.035)
    assert dispatcher.poll(0.0) is None  # no plan yet
    dispatcher.take(_plan(0.0, 2), 0.0005)
    assert dispatcher.active and dispatcher.round_trip_s == pytest.approx(0.0005)
    sent = {}
    for j in range(100):  # 1 ms polls
        now = 0.001 + j * 0.001
        values = dispatcher.poll(now)
        if values is not None:
            sent[round(now, 6)] = values
    assert sent == {0.001: (1.0, -1.0, 0.0), 0.01: (2.0, -2.0, 0.5), 0.02: ZERO, 0.03: ZERO, 0.04: ZERO,
                    0.05: ZERO}
    assert not dispatcher.active and follower.counts["exhausted_periods"] == 4
    reports = [r for r in follower.pop_reports() if r.values is not None]
    assert [(r.time_s, r.entry_index) for r in reports[:2]] == [(0.0, 0), (TS, 1)]  # at the entries' starts


# RobotLoop ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("interface", ["voltages", "cmd_vel"])
def test_a_period_of_the_robot_loop_is_the_plant_stepped_by_hand(interface):
    plant, twin = RobotinoPlant(ROBOT), RobotinoPlant(ROBOT)
    drive = VoltageDrive(plant) if interface == "voltages" else TwistDrive(plant, WheelSpeedLoop(ROBOT))
    robot = RobotLoop(plant, plant, drive, TS, PoseNoise((0.001, 0.002), seed=3, ticks=5))
    rng = np.random.default_rng(3)
    speed_loop = WheelSpeedLoop(ROBOT)
    for k in range(5):
        command = (2.0, -1.0, 0.5 * k) if interface == "voltages" else (0.1, 0.05 * k, 0.2)
        pose, twist = robot.measure()
        assert (pose, twist) == twin.odometry(rng, (0.001, 0.002))  # one draw per tick, same stream
        applied, trace = robot.drive(command)
        if interface == "voltages":
            twin.step(command, TS)
            assert applied == list(command)
            np.testing.assert_array_equal(trace, twin.substep_currents)
        else:
            held, currents = speed_loop.run(twin, command, TS)
            assert applied == held.mean(axis=0).tolist()
            np.testing.assert_array_equal(trace, currents)
        np.testing.assert_array_equal(plant.state, twin.state)


def test_the_noise_stream_drawn_ahead_equals_one_draw_per_measurement():
    ahead, per_tick = PoseNoise((0.01, 0.02), 9, ticks=4), PoseNoise((0.01, 0.02), 9)
    assert [ahead.draw() for _ in range(4)] == [per_tick.draw() for _ in range(4)]
    assert PoseNoise((0.0, 0.0), 9).draw() is None


# the realtime grid -------------------------------------------------------------------------------------------------
def _grid(follower=None, timeout_s=0.1):
    plant = RobotinoPlant(ROBOT)
    robot = RobotLoop(plant, plant, VoltageDrive(plant), TS, PoseNoise((0.0, 0.0), 0))
    return robot, RealtimeGrid(robot, 100.0, 1000.0, timeout_s, follower, offset_ns=5_000_000_000)


def test_realtime_measures_each_grid_point_once_so_stamps_increase():
    """A publish timer that fires again before the grid has advanced (a late timer catching up: CI saw two odometry
    stamps 210 ns apart, the later one first) measures nothing; each measurement is a new grid point, stamped on the
    robot clock (steady + the offset handed in).
    """
    robot, grid = _grid()
    stamps = []
    for after_s in (0.0103, 0.0105, 0.0202):
        measurement, _ = grid.measure(100.0 + after_s, 7_000_000_000)
        stamps.append(None if measurement is None else measurement.stamp_ns)
    assert stamps == [7_000_000_000 + round((100.0 + 0.010) * 1e9), None,
                      7_000_000_000 + round((100.0 + 0.020) * 1e9)]
    assert grid.simulated_s == pytest.approx(0.020)


def test_realtime_command_holds_from_the_next_grid_point_and_the_watchdog_zeroes_it_once():
    robot, grid = _grid(timeout_s=0.005)
    twin = RobotinoPlant(ROBOT)
    grid.hold_command((3.0, -3.0, 1.0), 100.0025)  # drives 0..3 ms at zero, holds from 3 ms
    _, logs = grid.advance(100.0125)  # 3..8 ms with the command (stale after 7.5 ms: from the 8 ms point), 8..12 zero
    twin.step(np.zeros(3), 0.003)
    twin.step(np.array([3.0, -3.0, 1.0]), 0.005)
    twin.step(np.zeros(3), 0.004)
    np.testing.assert_allclose(robot.plant.state, twin.state, rtol=0, atol=1e-12)
    assert robot.counts["command_timeouts"] == 1 and [log.key for log in logs] == ["timeout"]
    _, logs = grid.advance(100.02)
    assert robot.counts["command_timeouts"] == 1 and logs == []  # once per command


def test_realtime_stall_is_skipped_not_integrated():
    robot, grid = _grid()
    _, logs = grid.advance(102.5)
    assert robot.plant.time_s == 0.0 and grid.simulated_s == pytest.approx(2.5)
    assert [log.key for log in logs] == ["behind"]


def test_realtime_plans_drive_each_control_period_with_the_entry_chosen_at_its_start():
    follower = PlanFollower(TS)
    robot, grid = _grid(follower)
    origin = 105.0  # robot clock of the grid's origin (steady 100 + offset 5)
    reason, _ = grid.take_plan(_plan(origin, 3), 100.0)  # at period 0's start, yet after its command was chosen
    assert reason is None
    grid.take_plan(_plan(origin + 0.005, 3, first=origin + TS, value=10.0), 100.005)  # within period 0
    grid.advance(100.0305)
    twin = RobotinoPlant(ROBOT)
    for values in (ZERO, (10.0, -10.0, 0.0), (11.0, -11.0, 0.5)):  # period 0: zero; then the newest plan's entries
        twin.step(np.array(values), TS)
    np.testing.assert_allclose(robot.plant.state, twin.state, rtol=0, atol=1e-12)


# the chain emulation on a clock handed in -------------------------------------------------------------------------
def test_the_chain_robot_dispatches_the_emulators_odometry_at_its_passes_stamped_on_the_node_clock():
    """Against a twin `ChainEmulator` run pass by pass: the same messages, stamped the node clock at the first poll
    plus their pass time; per pass with firmware ticks, the peaks and the mean voltages of those ticks.
    """
    from robotino_geom_mpc.loop.chain_robot import ChainRobot
    from robotino_geom_mpc.model.chain_emulation import ChainEmulator
    from robotino_geom_mpc.model.driver_chain import ChainParams

    chain = ChainParams()
    robot = ChainRobot(ChainEmulator(RobotinoPlant(ROBOT), chain, seed=4))
    twin = ChainEmulator(RobotinoPlant(ROBOT), chain, seed=4)
    assert not robot.cmd_vel((0.1, 0.0, 0.0), 50.0)  # before the first poll: nothing to forward it to
    start_ns = 1_000_000_000
    assert robot.poll(50.0, start_ns) == []  # starts the emulation at t = 0; the driver's first pass comes later
    assert robot.cmd_vel((0.2, 0.0, 0.5), 50.0)
    twin.cmd_vel((0.2, 0.0, 0.5), 0.0)
    twin_passes = []
    passes = robot.poll(50.3, start_ns + 10**9)  # a later node clock is not used: stamps count from the start
    while twin.next_pass_s() <= 0.3:
        twin_passes.append((twin.run_until(twin.next_pass_s()), len(twin.trace)))
    assert len(passes) == len(twin_passes)
    before = 0
    for got, (messages, ticks) in zip(passes, twin_passes):
        assert [(m.stamp_ns, m.pose, m.twist) for m in got.odometry] == [
            (start_ns + int(round(m.stamp_s * 1e9)), m.pose, m.twist) for m in messages]
        records = twin.trace[before:ticks]
        assert (got.state is None) == (not records)
        if records:
            np.testing.assert_allclose(np.abs(got.state.currents), np.abs([r.currents for r in records]).max(axis=0),
                                       rtol=0, atol=0)
            np.testing.assert_allclose(got.state.applied_voltages, np.mean([r.voltages for r in records], axis=0),
                                       rtol=0, atol=1e-12)
        before = ticks
    dispatched = [m for p in passes for m in p.odometry]
    assert len(dispatched) > 10 and robot.dispatched == len(dispatched) and robot.commands == 1
    assert dispatched[-1].pose[2] > 0.01  # the forwarded twist turned the robot
    assert robot.emulator.plant.state.tolist() == twin.plant.state.tolist()
    assert max(p.late_s for p in passes) > 0.05  # polled 0.3 s late: the passes ran behind their times
