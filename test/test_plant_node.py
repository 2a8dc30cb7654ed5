"""The plant simulator node alone over DDS: a harness node drives it in lockstep and checks what it publishes."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from tf2_msgs.msg import TFMessage

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.messages import quaternion_to_yaw, stamp_to_ns
from robotino_geom_mpc.ros.qos import PUBLISH_QOS
from harness import Harness
from robotino_geom_mpc.system.processes import NodeGroup, ros_args
from robotino_geom_mpc.model.plant import RobotinoPlant

pytestmark = pytest.mark.ros

NOISE = (0.002, 0.003)
SEED = 7


def _pose(msg):
    p = msg.pose.pose.position
    return np.array([p.x, p.y, quaternion_to_yaw(msg.pose.pose.orientation)])


@pytest.fixture(scope="module")
def plant_run(tmp_path_factory):
    """A lockstep plant of 4 ticks driven by the harness: commands, what came back, the exit status."""
    robot, control = load_params()
    Ts = control.period_s
    commands = [[2.0, -1.0, 0.5], [math.nan, 0.0, 0.0], [1.0, 2.0], [0.0, 3.0, -3.0]]
    report = tmp_path_factory.mktemp("plant_report") / "timing.json"
    with NodeGroup(log_dir=tmp_path_factory.mktemp("plant")) as group, Harness("plant_test") as h:
        odom = h.collect("odom", Odometry)
        truth = h.collect("ground_truth/odom", Odometry)
        clock = h.collect("/clock", Clock)
        currents = h.collect("wheel_currents", Float64MultiArray)
        joints = h.collect("joint_states", JointState)
        tf = h.collect("/tf", TFMessage)
        pub = h.node.create_publisher(Float64MultiArray, "wheel_voltages", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {
            "mode": "lockstep", "duration_s": 4 * Ts, "lockstep_wait_for": ["odom:1", "/clock:1"],
            "odometry_noise.position_m": NOISE[0], "odometry_noise.yaw_rad": NOISE[1], "seed": SEED,
            "lockstep_resend_s": 0.3, "timing_report": str(report),
        }))
        assert h.spin_until(lambda: len(odom) >= 1, 30.0), plant.stderr_tail()
        # no command for tick 0: the plant resends it (same stamp, same measurement)
        assert h.spin_until(lambda: len(odom) >= 2, 5.0)
        graph = dict(h.node.get_topic_names_and_types())
        infos = h.node.get_publishers_info_by_topic("/odom")
        for k, command in enumerate(commands):
            h.spin_until(lambda: len(truth) >= k + 1, 5.0)  # tick k (a resent tick has no new ground truth)
            pub.publish(Float64MultiArray(data=command))
            assert h.spin_until(lambda: len(currents) >= k + 1, 10.0), plant.stderr_tail()
        assert group.wait(plant, 10.0)
        h.spin_for(0.2)
        return dict(robot=robot, Ts=Ts, commands=commands, odom=odom, truth=truth, clock=clock,
                    currents=currents, joints=joints, tf=tf, graph=graph, infos=infos, status=plant.popen.returncode,
                    stderr=plant.stderr_tail(50), report=json.loads(report.read_text()))


def test_topics_types_and_qos(plant_run):
    graph = plant_run["graph"]
    assert graph["/odom"] == ["nav_msgs/msg/Odometry"]
    assert graph["/ground_truth/odom"] == ["nav_msgs/msg/Odometry"]
    assert graph["/wheel_currents"] == ["std_msgs/msg/Float64MultiArray"]
    assert graph["/joint_states"] == ["sensor_msgs/msg/JointState"]
    assert graph["/clock"] == ["rosgraph_msgs/msg/Clock"]
    (info,) = plant_run["infos"]
    assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    assert info.qos_profile.durability == DurabilityPolicy.VOLATILE


def test_lockstep_timing_report(plant_run):
    report, Ts = plant_run["report"], plant_run["Ts"]
    assert report["mode"] == "lockstep"
    assert report["ticks"] == 4 and report["loop_ticks"] == 3  # duration_s / Ts; ticks 1 .. n - 1
    assert report["simulated_s"] == pytest.approx(3 * Ts)
    assert report["realtime_factor"] == pytest.approx(report["simulated_s"] / report["wall_s"])
    assert (report["answered"], report["missed"], report["missed_ticks"], report["latency_ms"]) == (4, 0, [], None)
    assert report["resent"] >= 1 and report["refused_commands"] == 2 and report["clamped_commands"] == 0
    assert report["tick0_answer_s"] >= 0.3  # tick 0 was resent after 0.3 s without a command
    assert report["wait_ms_per_tick"] > 0 and report["plant_busy_ms_per_tick"] > 0
    assert "no command for tick 0 (t = 0.000 s) for 0." in plant_run["stderr"]


def test_stamps_clock_frames_and_resend(plant_run):
    Ts_ns = round(plant_run["Ts"] * 1e9)
    odom = plant_run["odom"]
    stamps = [stamp_to_ns(m.header.stamp) for m in odom]
    assert stamps == [0, 0] + [k * Ts_ns for k in range(1, 4)]  # tick 0 resent once, then one per command
    assert np.array_equal(_pose(odom[0]), _pose(odom[1]))  # the resent tick is the same measurement
    assert [stamp_to_ns(c.clock) for c in plant_run["clock"]] == stamps
    for msg in odom + plant_run["truth"]:
        assert (msg.header.frame_id, msg.child_frame_id) == ("odom", "base_link")
    # the resend is odometry and /clock only: tf2 refuses a transform stamped again (TF_REPEATED_DATA)
    ticks = [k * Ts_ns for k in range(4)]
    assert [stamp_to_ns(m.header.stamp) for m in plant_run["truth"]] == ticks
    assert [stamp_to_ns(m.header.stamp) for m in plant_run["joints"]] == ticks
    assert [stamp_to_ns(t.header.stamp) for m in plant_run["tf"] for t in m.transforms] == ticks


def test_states_match_an_offline_plant_with_bad_commands_as_zero_volts(plant_run):
    robot, Ts = plant_run["robot"], plant_run["Ts"]
    offline = RobotinoPlant(robot)
    truth = plant_run["truth"]
    applied = [[2.0, -1.0, 0.5], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 3.0, -3.0]]
    for k, U in enumerate(applied):
        assert np.allclose(_pose(truth[k]), offline.pose, rtol=0, atol=1e-12)
        offline.step(np.array(U), Ts)
        expected = np.copysign(offline.peak_abs_currents, offline.currents)
        assert np.allclose(plant_run["currents"][k].data, expected, rtol=1e-12, atol=1e-15)
        assert plant_run["currents"][k].layout.dim[0].label == "wheel_current_a"
        if k + 1 < len(truth):
            t = truth[k + 1]
            assert np.allclose(_pose(t), offline.pose, rtol=0, atol=1e-12)
            c, s = math.cos(offline.pose[2]), math.sin(offline.pose[2])
            v = offline.body_state[[1, 3, 5]]
            body = (c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2])  # twist in base_link
            tw = t.twist.twist
            assert np.allclose((tw.linear.x, tw.linear.y, tw.angular.z), body, rtol=0, atol=1e-12)
            joint = [j for j in plant_run["joints"] if stamp_to_ns(j.header.stamp) == stamp_to_ns(t.header.stamp)][0]
            assert list(joint.name) == ["wheel0_joint", "wheel1_joint", "wheel2_joint"]
            assert np.allclose(joint.velocity, offline.wheel_speeds, rtol=0, atol=1e-12)
            torque = robot.gear_ratio * robot.torque_constant_n_m_per_a * offline.currents
            assert np.allclose(joint.effort, torque, rtol=0, atol=1e-12)


def test_odometry_noise_and_covariance(plant_run):
    rng = np.random.default_rng(SEED)  # the noise stream of simulation.run_scenario
    sigma = np.array([NOISE[0], NOISE[0], NOISE[1]])
    odom = [m for i, m in enumerate(plant_run["odom"]) if i != 1]
    truth = plant_run["truth"]  # one per tick: the resend repeats only the odometry
    for o, t in zip(odom, truth):
        expected = rng.normal(0.0, sigma)
        assert np.allclose(_pose(o) - _pose(t), expected, rtol=1e-9, atol=1e-12)
        cov = np.array(o.pose.covariance).reshape(6, 6)
        assert np.allclose(np.diag(cov)[[0, 1, 5]], sigma**2)
        assert np.count_nonzero(cov - np.diag(np.diag(cov))) == 0
        assert np.allclose(np.array(t.pose.covariance).reshape(6, 6)[[0, 1, 5], [0, 1, 5]], 1e-12)


def test_ends_after_the_last_tick_cleanly(plant_run):
    assert plant_run["status"] == 0
    assert "Traceback" not in plant_run["stderr"]


@pytest.mark.parametrize("override, name", [
    ({"odometry_noise.position_m": -0.1}, "odometry_noise.position_m"),
    ({"robot.mass_kg": 0.0}, "robot.mass_kg"),
    ({"mode": "fast"}, "mode"),
    ({"odometry_model": "lidar"}, "odometry_model"),
    ({"encoder.counts_per_rev": 0}, "encoder.counts_per_rev"),
    ({"encoder.wheel_slip_std": 1.5}, "encoder.wheel_slip_std"),
    ({"lockstep_max_realtime_factor": -1.0}, "lockstep_max_realtime_factor"),
])
def test_refuses_to_start_with_a_bad_parameter(override, name):
    proc = subprocess.run([sys.executable, "-m", "robotino_sim_node.plant_node", *ros_args(None, override)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert name in proc.stderr and "Traceback" not in proc.stderr


def test_lockstep_max_realtime_factor_caps_the_loop(tmp_path):
    """At most 0.5 simulated seconds a wall second: tick k + 1 goes out 2 Ts after tick k at the soonest (tick 1
    at once), so the run's factor over ticks 1 .. n - 1 is at most 0.5 (n - 1) / (n - 2). Unpaced, this loop
    answered by the harness runs tens of times faster than real time.
    """
    _, control = load_params()
    factor, n, Ts = 0.5, 21, control.period_s
    report = tmp_path / "timing.json"
    with NodeGroup(log_dir=tmp_path) as group, Harness("plant_pace_test") as h:
        stamps = set()
        h.node.create_subscription(Odometry, "odom", lambda m: stamps.add(stamp_to_ns(m.header.stamp)), PUBLISH_QOS)
        pub = h.node.create_publisher(Float64MultiArray, "wheel_voltages", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {
            "mode": "lockstep", "duration_s": n * Ts, "lockstep_wait_for": ["odom:1"],
            "lockstep_max_realtime_factor": factor, "timing_report": str(report)}))
        for k in range(n):
            assert h.spin_until(lambda: round(k * Ts * 1e9) in stamps, 10.0), plant.stderr_tail()
            pub.publish(Float64MultiArray(data=[1.0, 0.0, -1.0]))
        assert group.wait(plant, 10.0) and plant.popen.returncode == 0, plant.stderr_tail()
    timing = json.loads(report.read_text())
    assert timing["ticks"] == n and timing["simulated_s"] == pytest.approx((n - 1) * Ts)
    print(f"\nlockstep_max_realtime_factor {factor}: the run's factor {timing['realtime_factor']:.3f}")
    assert timing["realtime_factor"] <= factor * (n - 1) / (n - 2)


def test_encoder_odometry_is_published_and_drifts_from_the_ground_truth(tmp_path):
    """A lockstep plant with ``odometry_model: encoders``: odom is the offline dead reckoning, the truth is not."""
    from robotino_geom_mpc.model.encoders import EncoderOdometry, twist_covariance

    robot, control = load_params()
    Ts, ticks = control.period_s, 30
    with NodeGroup(log_dir=tmp_path) as group, Harness("plant_encoders") as h:
        odom = h.collect("odom", Odometry)
        truth = h.collect("ground_truth/odom", Odometry)
        pub = h.node.create_publisher(Float64MultiArray, "wheel_voltages", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {
            "mode": "lockstep", "duration_s": ticks * Ts, "lockstep_wait_for": ["odom:1", "ground_truth/odom:1"],
            "odometry_model": "encoders", "encoder.counts_per_rev": 512, "lockstep_resend_s": 5.0,
        }))
        for k in range(ticks):
            assert h.spin_until(lambda: len(odom) >= k + 1 and len(truth) >= k + 1, 30.0), plant.stderr_tail()
            pub.publish(Float64MultiArray(data=[6.0 + 0.2 * k, -4.0, 3.0 - 0.3 * k]))
        assert group.wait(plant, 10.0) and plant.popen.returncode == 0, plant.stderr_tail()
    offline = RobotinoPlant(robot)
    encoders = EncoderOdometry(offline, 512)
    for k in range(ticks):
        pose, twist = encoders.update()
        tw = odom[k].twist.twist
        assert np.allclose(_pose(odom[k]), pose, rtol=0, atol=1e-12)
        assert np.allclose((tw.linear.x, tw.linear.y, tw.angular.z), twist, rtol=0, atol=1e-12)
        assert np.allclose(_pose(truth[k]), offline.pose, rtol=0, atol=1e-12)
        true_twist = truth[k].twist.twist
        assert np.allclose((true_twist.linear.x, true_twist.linear.y, true_twist.angular.z),
                           offline.odometry()[1], rtol=0, atol=1e-12)
        offline.step(np.array([6.0 + 0.2 * k, -4.0, 3.0 - 0.3 * k]), Ts)
    assert np.abs(_pose(odom[-1]) - _pose(truth[-1])).max() > 1e-6  # 512 counts: visibly off the truth
    # the twist's covariance is the encoders' bound (x, y, yaw), the ground truth's stays certain
    bound = twist_covariance(robot, 512, 0.0, Ts)
    assert np.array_equal(np.array(odom[0].twist.covariance).reshape(6, 6)[np.ix_([0, 1, 5], [0, 1, 5])], bound)
    assert np.allclose(np.array(truth[0].twist.covariance), np.diag([1e-12] * 6).ravel(), rtol=0, atol=0)


def _full_state(truth: Odometry, joints: JointState, effort_per_a: float) -> np.ndarray:
    """(x, x', y, y', theta, theta', i_1..3) from a ground-truth odometry and the joint efforts of the same stamp."""
    x, y, theta = _pose(truth)
    tw = truth.twist.twist
    c, s = math.cos(theta), math.sin(theta)
    vx, vy = c * tw.linear.x - s * tw.linear.y, s * tw.linear.x + c * tw.linear.y
    return np.array([x, vx, y, vy, theta, tw.angular.z, *(np.array(joints.effort) / effort_per_a)])


def _paired_samples(truth, joints, effort_per_a):
    """(stamp [ns], full state) of every ground truth with the joint states of its stamp, in stamp order."""
    joint_by_stamp = {stamp_to_ns(m.header.stamp): m for m in joints}
    stamps = [(stamp_to_ns(m.header.stamp), m) for m in list(truth)]
    return sorted(((t, _full_state(m, joint_by_stamp[t], effort_per_a)) for t, m in stamps if t in joint_by_stamp),
                  key=lambda sample: sample[0])


def _hold_windows(samples, timeout_s, grid_s, span_s=0.4):
    """The samples certainly under the held command and certainly after the watchdog, from the plant's own stamps
    (each window at most `span_s` long: the offline plant is compared over spans of that order).

    A command received at steady time a holds from grid point g_a = ceil(a / dt) to the stale point
    floor((a + timeout) / dt) + 1 (`CommandHold`), so the last sample at rest t0 <= g_a < the first moved one t1:
    the command holds over [t1, t0 + timeout - dt] and zero volts from t1 + timeout + dt on (each a grid step more
    for the stamps' rounding). No assumption on when the command arrived: load cannot move the windows.
    """
    moved = next((i for i, (_, s) in enumerate(samples) if s.any()), None)
    if not moved:
        return None, [], []
    t0, t1 = samples[moved - 1][0], samples[moved][0]
    during = [(t, s) for t, s in samples if t1 <= t <= min(t0 + (timeout_s - 2 * grid_s) * 1e9, t1 + span_s * 1e9)]
    zero = t1 + (timeout_s + 2 * grid_s) * 1e9
    after = [(t, s) for t, s in samples if zero <= t <= zero + span_s * 1e9]
    return moved, during, after


@pytest.fixture(scope="module")
def realtime_run(tmp_path_factory):
    """A realtime plant: the harness sends one command, then waits for the plant's samples well past its timeout."""
    robot, control = load_params()
    command = [6.0, -2.0, 1.0]
    timeout, grid = 0.5, 1e-3
    effort = robot.gear_ratio * robot.torque_constant_n_m_per_a
    with NodeGroup(log_dir=tmp_path_factory.mktemp("plant_rt")) as group, Harness("plant_rt_test") as h:
        truth = h.collect("ground_truth/odom", Odometry)
        joints = h.collect("joint_states", JointState)
        pub = h.node.create_publisher(Float64MultiArray, "wheel_voltages", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {
            "mode": "realtime", "command_timeout_s": timeout, "physics_rate_hz": 1.0 / grid}))
        assert h.spin_until(lambda: len(truth) >= 3 and pub.get_subscription_count() >= 1, 30.0), plant.stderr_tail()
        pub.publish(Float64MultiArray(data=command))
        # the test waits on the loop: until the plant's samples reach 25 past the watchdog, however long that takes
        assert h.spin_until(lambda: len(_hold_windows(_paired_samples(truth, joints, effort), timeout, grid)[2]) >= 25,
                            120.0), plant.stderr_tail()
        (rate_set,) = h.set_parameters("robotino_plant", {"physics_rate_hz": 500.0})
        group.stop_node(plant)
    return dict(robot=robot, command=command, timeout=timeout, grid=grid,
                samples=_paired_samples(truth, joints, effort), rate_set=rate_set)


def _offline(robot, state, voltages, seconds, grid=1e-3):
    plant = RobotinoPlant(robot, state0=state[:9])
    steps = round(seconds / grid)
    for _ in range(steps):
        plant.step(np.array(voltages, dtype=float), grid)
    return plant.state


def test_realtime_holds_the_command_and_zero_volts_after_the_timeout(realtime_run):
    run = realtime_run
    samples = run["samples"]
    moved, during, after = _hold_windows(samples, run["timeout"], run["grid"])
    assert moved and not any(s.any() for _, s in samples[:moved])  # at rest, zero volts, until the command
    # under the command: the offline plant under the command from the first sample of the window to its last
    assert len(during) >= 20
    (t_a, s_a), (t_b, s_b) = during[0], during[-1]
    # (rtol: the grid's chunks against one step over the window round differently, ~1e-7 of a decayed current)
    np.testing.assert_allclose(_offline(run["robot"], s_a, run["command"], (t_b - t_a) * 1e-9), s_b, rtol=1e-6,
                               atol=2e-9)
    assert math.hypot(s_b[1], s_b[3]) > 0.1  # the command really drives the robot
    # after the timeout: the offline plant under zero volts (the currents decay)
    (t_a, s_a), (t_b, s_b) = after[0], after[-1]
    np.testing.assert_allclose(_offline(run["robot"], s_a, [0.0, 0.0, 0.0], (t_b - t_a) * 1e-9), s_b, rtol=1e-6,
                               atol=2e-9)
    assert np.abs(s_b[6:9]).max() < 0.5 * np.abs(s_a[6:9]).max()


def test_realtime_grid_rate_cannot_change_while_running(realtime_run):
    assert not realtime_run["rate_set"].successful and "physics_rate_hz" in realtime_run["rate_set"].reason
