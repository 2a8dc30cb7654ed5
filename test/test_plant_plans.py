"""The plant node with plans: bad plans refused (logged, counted, the plans held stay), what it applied reported
and checked against its own plant driven step by step; link parameters out of range refused by name.
"""

import math

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from trajectory_msgs.msg import JointTrajectory

from harness import Harness
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.network.plan import CommandPlan
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.plans import plan_message, report_of_message
from robotino_geom_mpc.ros.qos import PUBLISH_QOS
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

pytestmark = pytest.mark.ros

TICKS = 6


def _plan(basis, first, values, period):
    return CommandPlan(basis, tuple(first + i * period for i in range(len(values))), tuple(values), period)


@pytest.fixture(scope="module")
def plan_run(tmp_path_factory):
    """A lockstep plant with plans, no link: per tick a good plan or a bad one; the odometry and the reports."""
    robot, control = load_params()
    Ts = control.period_s
    good = _plan(0.0, 0.0, [(2.0, -1.0, 0.5), (1.0, 1.0, 1.0), (0.5, 0.0, -0.5), (0.0, 2.0, 0.0)], Ts)
    bad = [  # ticks 1-4: each refused; the plan of tick 0 stays
        _plan(Ts, Ts, [(math.nan, 0.0, 0.0)] * 3, Ts),  # NaN
        CommandPlan(2 * Ts, (2 * Ts, 2 * Ts), ((9.0, 9.0, 9.0),) * 2, Ts),  # non-increasing times
        _plan(3 * Ts + 30.0, 3 * Ts + 30.0, [(9.0, 9.0, 9.0)], Ts),  # basis far in the future
        _plan(4 * Ts - 30.0, 4 * Ts - 30.0, [(9.0, 9.0, 9.0)], Ts),  # before time 0: no ROS time (``stamp``)
    ]
    wrong_length = plan_message(_plan(5 * Ts, 5 * Ts, [(9.0, 9.0, 9.0)] * 2, Ts), "voltages")
    wrong_length.points[1].effort = [1.0, 2.0]  # tick 5: two voltages
    messages = [plan_message(good, "voltages")] + [plan_message(p, "voltages") for p in bad] + [wrong_length]
    with NodeGroup(log_dir=tmp_path_factory.mktemp("plant_plans")) as group, Harness("plant_plans_test") as h:
        odom = h.collect("odom", Odometry)
        reports = h.collect("command_applied", JointTrajectory)
        pub = h.node.create_publisher(JointTrajectory, "wheel_voltage_plan", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {
            "mode": "lockstep", "plans": True, "duration_s": TICKS * Ts, "lockstep_resend_s": 5.0,
            "lockstep_wait_for": ["odom:1", "command_applied:1"]}))
        for k, msg in enumerate(messages):
            assert h.spin_until(lambda: len(odom) >= k + 1, 30.0), plant.stderr_tail()
            pub.publish(msg)
        assert plant.popen.wait(30.0) == 0, plant.stderr_tail()
        h.spin_for(0.5)
    return robot, Ts, good, odom, [report_of_message(m) for m in reports], plant.stderr_tail(60)


def test_bad_plans_are_refused_logged_and_the_plan_held_stays(plan_run):
    robot, Ts, good, odom, reports, log = plan_run
    applied = [r for r in reports if r.values is not None]
    assert [round(r.time_s / Ts) for r in applied] == list(range(TICKS))
    # entries 0-3 of the good plan, then zero (it is used up): every refused plan left it in place
    want = [good.entries[k] if k < len(good.entries) else (0.0, 0.0, 0.0) for k in range(TICKS)]
    assert [r.values for r in applied] == [pytest.approx(v) for v in want]
    assert [r.basis_s for r in applied[:4]] == [0.0] * 4 and applied[4].basis_s is None
    receipts = [(round(r.time_s / Ts), r.taken) for r in reports if r.values is None]
    # ticks 4 and 5 (no time, wrong length) cannot be read: no receipt; the buffer test covers ``past``
    assert receipts == [(0, True), (1, False), (2, False), (3, False)]
    assert "refused wheel_voltage_plan (nan" in log  # the first refusal (the warning is throttled)


def test_the_reported_commands_drove_the_plant(plan_run):
    robot, Ts, good, odom, reports, _ = plan_run
    plant = RobotinoPlant(robot)
    for r in sorted((r for r in reports if r.values is not None), key=lambda r: r.time_s)[:TICKS - 1]:
        plant.step(np.array(r.values), Ts)
        msg = next(m for m in odom if round((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9) / Ts)
                   == round(r.time_s / Ts) + 1)
        p = msg.pose.pose.position
        np.testing.assert_allclose((p.x, p.y), plant.pose[:2], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name, value, message", [
    ("link.up.loss", 1.0, "link.up.loss"),
    ("link.down.delay_s", 11.0, "link.down.delay_s"),
    ("link.up.burst_length", 0.5, "link.up.burst_length"),
    ("link.down.loss", 0.9, "link.down.loss"),  # needs bursts of 9 packets or more
])
def test_a_link_parameter_out_of_range_is_refused_by_name(tmp_path, name, value, message):
    with NodeGroup(log_dir=tmp_path) as group:
        plant = group.start("plant_node", ros_args(None, {name: value}))
        status = plant.popen.wait(60.0)
    assert status == 2, plant.stderr_tail()
    assert message in plant.stderr_tail()


def test_a_link_parameter_set_out_of_range_is_refused_by_name(tmp_path):
    with NodeGroup(log_dir=tmp_path) as group, Harness("link_set") as h:
        group.start("plant_node", ros_args(None, {"mode": "lockstep"}))
        assert h.spin_until(lambda: h.node.count_publishers("/odom") > 0, 30.0)
        result = h.set_parameters("robotino_plant", {"link.up.jitter_s": -1.0})
    assert not result[0].successful and "link.up.jitter_s" in result[0].reason


@pytest.fixture(scope="module")
def realtime_plan_run(tmp_path_factory):
    """A realtime plant with plans, no link: per odometry a plan, every third one late (its first entry in the
    period already running when it arrives); the ground truth and the reports.
    """
    robot, control = load_params()
    Ts = control.period_s
    rng = np.random.default_rng(7)
    with NodeGroup(log_dir=tmp_path_factory.mktemp("plant_plans_rt")) as group, Harness("plant_plans_rt") as h:
        truth = h.collect("ground_truth/odom", Odometry)
        odom = h.collect("odom", Odometry)
        reports = h.collect("command_applied", JointTrajectory)
        pub = h.node.create_publisher(JointTrajectory, "wheel_voltage_plan", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {"mode": "realtime", "plans": True, "duration_s": 3.0}))
        answered, late = 0, set()

        def more() -> bool:  # an odometry to answer, or the plant's end (not a 10 s wait after its last)
            return len(odom) > answered or plant.popen.poll() is not None

        while h.spin_until(more, 10.0) and len(odom) > answered:
            stamp = odom[-1].header.stamp
            basis = (stamp.sec * 1_000_000_000 + stamp.nanosec) * 1e-9  # as `ros.plans` reads stamps
            answered = len(odom)
            lead = 0 if answered % 3 == 0 else 1  # lead 0: the first entry's period has begun at its arrival
            if lead == 0:
                late.add(basis)
            pub.publish(plan_message(_plan(basis, basis + lead * Ts, [tuple(rng.uniform(-3.0, 3.0, 3))
                                                                        for _ in range(4)], Ts), "voltages"))
        assert plant.popen.wait(30.0) == 0, plant.stderr_tail()
        h.spin_for(0.5)
    stamps_ns = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in odom]
    return robot, Ts, stamps_ns, truth, [report_of_message(m) for m in reports], late


def test_realtime_odometry_is_measured_on_the_control_grid(realtime_plan_run):
    robot, Ts, stamps_ns, _, reports, _ = realtime_plan_run
    assert len(stamps_ns) > 100
    period_ns = round(Ts * 1e9)
    off_grid = lambda ns: min((ns - stamps_ns[0]) % period_ns, -(ns - stamps_ns[0]) % period_ns)  # noqa: E731
    # on the grid to the float rounding of stamps near 1.8e9 s (a few hundred ns): where the plans place entries
    assert max(map(off_grid, stamps_ns)) < 1000
    assert max(off_grid(round(r.time_s * 1e9)) for r in reports if r.values is not None) < 1000


def test_realtime_plan_taken_within_a_period_acts_from_the_next(realtime_plan_run):
    robot, Ts, _, _, reports, late = realtime_plan_run
    receipts = {r.basis_s: r.time_s for r in reports if r.values is None and r.taken}
    applied = [r for r in reports if r.values is not None and r.basis_s is not None]
    early = [r for r in applied if receipts[r.basis_s] > r.time_s + 1e-6]
    assert not early, "an entry ran in a period that began before its plan arrived"
    assert late & set(receipts), "no late plan was taken"
    assert all(r.entry_index >= 1 for r in applied if r.basis_s in late)  # entry 0's period had begun


def test_realtime_reported_commands_drove_the_plant(realtime_plan_run):
    """Step by step: the reported command of every period, from rest, gives the ground truth at each stamp."""
    robot, Ts, _, truth, reports, _ = realtime_plan_run
    by_period = {}
    for r in sorted((r for r in reports if r.values is not None), key=lambda r: r.time_s):
        by_period[round(r.time_s / Ts)] = r.values
    first, last = min(by_period), max(by_period)
    poses = {round((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9) / Ts): m.pose.pose.position for m in truth}
    plant, values = RobotinoPlant(robot), (0.0, 0.0, 0.0)
    start = poses[max(k for k in poses if k <= first)]  # at rest until the first plan's entry
    for k in range(first, last):
        values = by_period.get(k, values if values == (0.0, 0.0, 0.0) else None)  # an unreported period: no plan
        assert values is not None, f"period {k} ran an entry that was not reported"
        plant.step(np.array(values), Ts)
        if k + 1 in poses:
            p = poses[k + 1]
            np.testing.assert_allclose((p.x - start.x, p.y - start.y), plant.pose[:2], rtol=1e-9, atol=1e-9)
