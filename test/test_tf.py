"""/tf, joint_states and robot_description over DDS: a lockstep plant and the description publisher as processes.

Truths: the plant's own odometry messages (the /tf pose), the wheel kinematics written out here (rim speed
d_i . v + l omega of the published body twist; the wheel angles its integral), scipy's rotations with the
geometry of the parameter file (the wheels' TF), the shipped URDF file (robot_description), and
mcap-ros2-support reading a ``run`` bag.
"""

import glob
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from harness import Harness
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.messages import stamp_to_ns
from robotino_geom_mpc.system.processes import NodeGroup, ros_args
from robotino_geom_mpc.ros.qos import LOCKSTEP_PUBLISH_QOS, PUBLISH_QOS

pytestmark = pytest.mark.ros

tf2_msgs = pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs not installed ('make setup' builds it)")

ROOT = Path(__file__).resolve().parents[1]
URDF = (ROOT / "urdf" / "robotino.urdf").read_text()
PREFIX = "robot1/"
TICKS = 40
VOLTS = [6.0, -2.0, 3.0]  # turns and translates
BETA = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope="module")
def tf_run(tmp_path_factory):
    """A lockstep plant (frame prefix robot1/) driven for TICKS ticks, with the description publisher."""
    robot, control = load_params()
    with NodeGroup(log_dir=tmp_path_factory.mktemp("tf")) as group, Harness("tf_test") as h:
        odom = h.collect("odom", Odometry)
        joints = h.collect("joint_states", JointState)
        tf = h.collect("/tf", tf2_msgs.TFMessage)
        describer = group.start("robot_description_publisher", ros_args(None, {"frame_prefix": PREFIX}))
        pub = h.node.create_publisher(Float64MultiArray, "wheel_voltages", PUBLISH_QOS)
        plant = group.start("plant_node", ros_args(None, {
            "mode": "lockstep", "duration_s": TICKS * control.period_s, "frame_prefix": PREFIX,
            "lockstep_wait_for": ["odom:1", "joint_states:2", "/tf:1"]}))
        for k in range(TICKS):
            assert h.spin_until(lambda: len(odom) >= k + 1, 30.0), plant.stderr_tail()
            pub.publish(Float64MultiArray(data=VOLTS))
        assert group.wait(plant, 30.0), plant.stderr_tail()
        h.spin_until(lambda: sum(len(m.transforms) for m in tf) >= 4 * TICKS, 10.0)
        late = h.collect("robot_description", String, LATCHED)  # subscribed after it was published
        h.spin_until(lambda: late, 10.0)
        return dict(robot=robot, odom=odom, joints=joints, tf=tf, description=late, status=plant.popen.returncode,
                    describer=describer)


def _transforms(tf, parent, child):
    """Stamp [ns] -> (translation, quaternion xyzw) of the transforms parent -> child in the /tf messages."""
    out = {}
    for msg in tf:
        for t in msg.transforms:
            if t.header.frame_id == parent and t.child_frame_id == child:
                tr, q = t.transform.translation, t.transform.rotation
                out[stamp_to_ns(t.header.stamp)] = (np.array([tr.x, tr.y, tr.z]), np.array([q.x, q.y, q.z, q.w]))
    return out


def test_odom_to_base_link_on_tf_is_the_odometry_pose(tf_run):
    assert tf_run["status"] == 0
    odom = tf_run["odom"]
    assert len(odom) == TICKS
    assert {(m.header.frame_id, m.child_frame_id) for m in odom} == {(PREFIX + "odom", PREFIX + "base_link")}
    tf = _transforms(tf_run["tf"], PREFIX + "odom", PREFIX + "base_link")
    assert sorted(tf) == [stamp_to_ns(m.header.stamp) for m in odom]
    for m in odom:
        translation, q = tf[stamp_to_ns(m.header.stamp)]
        p, o = m.pose.pose.position, m.pose.pose.orientation
        np.testing.assert_allclose(translation, [p.x, p.y, p.z], atol=1e-9, rtol=0)
        np.testing.assert_allclose(q, [o.x, o.y, o.z, o.w], atol=1e-9, rtol=0)
    last = odom[-1].pose.pose
    assert math.hypot(last.position.x, last.position.y) > 1e-3 and abs(last.orientation.z) > 1e-3  # it moved


def test_joint_states_are_the_integral_of_the_wheel_speeds(tf_run):
    """Joint speeds = rim speeds of the odometry twist / r; angles = their integral (trapezoid, from 0)."""
    robot = tf_run["robot"]
    l, r = robot.wheel_distance_m, robot.wheel_radius_m
    by_stamp = {stamp_to_ns(m.header.stamp): m for m in tf_run["joints"]}
    stamps = [stamp_to_ns(m.header.stamp) for m in tf_run["odom"]]
    assert set(stamps) <= set(by_stamp)
    speeds, angles = [], []
    for m, stamp in zip(tf_run["odom"], stamps):
        v, w = m.twist.twist.linear, m.twist.twist.angular.z
        rim = [-math.sin(b) * v.x + math.cos(b) * v.y + l * w for b in BETA]  # d_i(0) . v + l omega
        joint = by_stamp[stamp]
        assert list(joint.name) == ["wheel0_joint", "wheel1_joint", "wheel2_joint"]
        np.testing.assert_allclose(joint.velocity, np.array(rim) / r, atol=1e-9, rtol=1e-9)
        speeds.append(np.array(rim) / r)
        angles.append(np.array(joint.position))
    t = (np.array(stamps) - stamps[0]) * 1e-9
    integral = np.vstack([np.zeros(3), np.cumsum(0.5 * np.diff(t)[:, None] * (np.array(speeds)[1:] + speeds[:-1]),
                                                 axis=0)])
    assert np.abs(angles[-1]).max() > 0.1  # the wheels turned
    np.testing.assert_allclose(np.array(angles), integral, atol=2e-4 * np.abs(angles[-1]).max())


def test_robot_description_reaches_a_late_subscriber(tf_run):
    assert [m.data for m in tf_run["description"]] == [URDF]


def test_wheel_tf_follows_joint_states(tf_run):
    robot = tf_run["robot"]
    l, r = robot.wheel_distance_m, robot.wheel_radius_m
    for i, beta in enumerate(BETA):
        tf = _transforms(tf_run["tf"], PREFIX + "base_link", f"{PREFIX}wheel{i}_link")
        assert len(tf) == TICKS
        for joint in tf_run["joints"]:
            translation, q = tf[stamp_to_ns(joint.header.stamp)]
            np.testing.assert_allclose(translation, [l * math.cos(beta), l * math.sin(beta), r], atol=1e-12)
            # joint frame turned by beta; the wheel turns about the axle pointing to the centre (-x)
            expected = Rotation.from_euler("z", beta) * Rotation.from_rotvec([-joint.position[i], 0.0, 0.0])
            assert abs(abs(np.dot(q, expected.as_quat())) - 1.0) < 1e-12


def test_publish_tf_off_means_no_tf_publisher(tmp_path):
    with NodeGroup(log_dir=tmp_path) as group, Harness("tf_off_test") as h:
        odom = h.collect("odom", Odometry)
        plant = group.start("plant_node", ros_args(None, {"mode": "realtime", "publish_tf": False}))
        assert h.spin_until(lambda: odom, 30.0), plant.stderr_tail()
        h.spin_for(0.5)
        assert h.node.get_publishers_info_by_topic("/odom")
        assert not h.node.get_publishers_info_by_topic("/tf")
        assert {(m.header.frame_id, m.child_frame_id) for m in odom} == {("odom", "base_link")}


@pytest.mark.parametrize("module", ["robotino_sim_node.plant_node", "robotino_geom_mpc.nodes.robot_description_node"])
@pytest.mark.parametrize("prefix", ["/robot1/", "robot1"])
def test_a_bad_frame_prefix_is_refused(module, prefix):
    proc = subprocess.run([sys.executable, "-m", module, *ros_args(None, {"frame_prefix": prefix})],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "frame_prefix" in proc.stderr and "Traceback" not in proc.stderr


def test_a_run_bag_read_by_mcap_ros2_holds_tf_and_the_robot_description(paper_circle_run):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out, proc, duration_s = paper_circle_run
    assert proc.returncode == 0, proc.stdout + proc.stderr
    odom, pairs, descriptions = {}, {}, []
    with open(glob.glob(str(out / "bag" / "*.mcap"))[0], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=["/odom", "/tf", "/robot_description"]):
            if channel.topic == "/odom":
                p = msg.pose.pose.position
                odom[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = (p.x, p.y)
            elif channel.topic == "/tf":
                for t in msg.transforms:
                    pairs.setdefault((t.header.frame_id, t.child_frame_id), {})[
                        (t.header.stamp.sec, t.header.stamp.nanosec)] = (t.transform.translation.x,
                                                                         t.transform.translation.y)
            else:
                descriptions.append(msg.data)
    assert descriptions == [URDF]
    assert set(pairs) == {("odom", "base_link"), *{("base_link", f"wheel{i}_link") for i in range(3)}}
    # every tick's pose, the same values
    assert len(odom) == round(duration_s / 0.01) and pairs[("odom", "base_link")] == odom
    for i in range(3):
        assert set(pairs[("base_link", f"wheel{i}_link")]) == set(odom)


def test_wheel_tf_of_other_joint_state_layouts(tmp_path):
    """The plant's layout goes the in-place path; other orders, an unknown name and a NaN the general one."""
    robot, _ = load_params()
    l, r = robot.wheel_distance_m, robot.wheel_radius_m
    sent = [  # (names, positions)
        (["wheel0_joint", "wheel1_joint", "wheel2_joint"], [0.1, -0.2, 0.3]),  # the plant's layout
        (["wheel2_joint", "wheel0_joint"], [1.5, -0.5]),  # other order, two joints
        (["caster", "wheel1_joint"], [9.0, 2.5]),  # a name the URDF does not have
        (["wheel0_joint", "wheel1_joint", "wheel2_joint"], [0.0, math.nan, 0.0]),  # skipped
    ]
    with NodeGroup(log_dir=tmp_path) as group, Harness("tf_layouts_test") as h:
        tf = h.collect("/tf", tf2_msgs.TFMessage)
        pub = h.node.create_publisher(JointState, "joint_states", PUBLISH_QOS)
        node = group.start("robot_description_publisher", ros_args(None, {}))
        assert h.spin_until(lambda: pub.get_subscription_count() > 0 and h.node.count_publishers("/tf") > 0,
                            30.0), node.stderr_tail()
        h.spin_for(1.0)  # the /tf reader matched on both sides
        for k, (names, positions) in enumerate(sent):
            msg = JointState(name=names, position=positions, velocity=[0.0] * len(names), effort=[0.0] * len(names))
            msg.header.stamp.sec = k + 1
            pub.publish(msg)
        assert h.spin_until(lambda: len(tf) >= 3, 10.0), node.stderr_tail()
        h.spin_for(0.5)
    assert [m.transforms[0].header.stamp.sec for m in tf] == [1, 2, 3]  # the NaN message gave none
    for msg, (names, positions) in zip(tf, sent):
        known = [(n, p) for n, p in zip(names, positions) if n.startswith("wheel")]
        assert [t.child_frame_id for t in msg.transforms] == [n.replace("_joint", "_link") for n, _ in known]
        for t, (name, position) in zip(msg.transforms, known):
            beta = BETA[int(name[5])]
            assert t.header.frame_id == "base_link" and t.header.stamp == msg.transforms[0].header.stamp
            tr, q = t.transform.translation, t.transform.rotation
            np.testing.assert_allclose([tr.x, tr.y, tr.z], [l * math.cos(beta), l * math.sin(beta), r], atol=1e-12)
            expected = Rotation.from_euler("z", beta) * Rotation.from_rotvec([-position, 0.0, 0.0])
            assert abs(abs(np.dot([q.x, q.y, q.z, q.w], expected.as_quat())) - 1.0) < 1e-12


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_stalled_description_publisher_loses_no_wheel_tf_in_lockstep(tmp_path, mode):
    """The publisher stopped (SIGSTOP) while BURST joint_states are sent, then resumed: in lockstep its keep-all
    reader and /tf writer turn every one into /tf, in order; in realtime its keep-last 100 reader cannot hold
    the burst DDS delivers at once on resume, so some are lost (what a `run` bag lost under a busy core).
    """
    burst = 1000
    with NodeGroup(log_dir=tmp_path) as group, Harness(f"tf_stall_{mode}") as h:
        tf = h.collect("/tf", tf2_msgs.TFMessage, LOCKSTEP_PUBLISH_QOS)
        pub = h.node.create_publisher(JointState, "joint_states", LOCKSTEP_PUBLISH_QOS)
        node = group.start("robot_description_publisher", ros_args(None, {"mode": mode}))
        assert h.spin_until(lambda: pub.get_subscription_count() > 0 and h.node.count_publishers("/tf") > 0,
                            30.0), node.stderr_tail()
        h.spin_for(1.0)  # the /tf reader matched on both sides
        names = ["wheel0_joint", "wheel1_joint", "wheel2_joint"]
        os.kill(node.popen.pid, signal.SIGSTOP)
        try:
            for k in range(burst):
                msg = JointState(name=names, position=[0.001 * k] * 3, velocity=[0.0] * 3, effort=[0.0] * 3)
                msg.header.stamp.sec = k + 1
                pub.publish(msg)
        finally:
            os.kill(node.popen.pid, signal.SIGCONT)
        h.spin_until(lambda: tf and tf[-1].transforms[0].header.stamp.sec == burst, 20.0)  # the last one
        h.spin_for(0.5)  # anything after it would show
    stamps = [m.transforms[0].header.stamp.sec for m in tf]
    if mode == "lockstep":
        assert stamps == list(range(1, burst + 1)), node.stderr_tail()
    else:
        assert len(stamps) < burst and stamps == sorted(stamps) and stamps[-1] == burst
