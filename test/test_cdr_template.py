"""`CdrTemplate`: patched bytes are the serialization of the message built the normal way, for each templated type.

Independent truths: rclpy's own deserializer (the message read back equals
the one built field by field) and rosbags' CDR reader/writer (a second
implementation: re-encoded, with zero padding, both byte strings are
identical, and the raw strings differ only at bytes that re-encode to zero,
i.e. the alignment padding rmw leaves uninitialised).
"""

import math
import sys

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, RegionOfInterest
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.ros import decode, messages
from robotino_geom_mpc.ros.cdr import CdrTemplate, CdrTemplateError
from robotino_geom_mpc.ros.messages import preview_message, preview_template, preview_values, three_values_layout, \
    three_values_template
from robotino_geom_mpc.description.urdf import JOINT_NAMES
from robotino_sim_node.outputs import ODOM_FIELDS, joint_template, odometry_values, plant_odometry

pytestmark = pytest.mark.unit

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
rng = np.random.default_rng(20261122)


def _same_wire(packed: bytes, msg, typename: str) -> None:
    """`packed` reads back as `msg` and equals its serialization but for alignment padding."""
    assert deserialize_message(packed, type(msg)) == msg
    normal = serialize_message(msg)
    assert len(packed) == len(normal)
    canon = TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(packed, typename), typename)
    assert canon == TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(normal, typename), typename)
    differ = np.flatnonzero(np.frombuffer(packed, np.uint8) != np.frombuffer(normal, np.uint8))
    assert all(i >= len(canon) or canon[i] == 0 for i in differ)  # only padding (alignment, trailing) may differ


def _stamp() -> tuple[int, int]:
    return int(rng.integers(0, 2**31)), int(rng.integers(0, 10**9))


def _floats(n: int) -> list[float]:
    return (rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)).tolist()


@pytest.mark.parametrize("noise", [(0.0, 0.0), (0.002, 0.003)])
def test_odometry_of_the_plant(noise):
    template = CdrTemplate(plant_odometry(*noise), ODOM_FIELDS)
    for _ in range(20):
        sec, nanosec = _stamp()
        x, y, theta, vx, vy, omega = _floats(3) + _floats(3)
        theta = float(rng.uniform(-20, 20))
        msg = plant_odometry(*noise)
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
        msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(theta / 2), math.cos(theta / 2)
        msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.angular.z = vx, vy, omega
        packed = template.pack(sec, nanosec, *odometry_values([x, y, theta], [vx, vy, omega]))
        _same_wire(packed, msg, "nav_msgs/msg/Odometry")
        assert msg.header.frame_id == "odom" and msg.child_frame_id == "base_link"


@pytest.mark.parametrize("label", ["wheel_current_a", "wheel_voltage_v"])
def test_three_value_arrays(label):
    template, layout = three_values_template(label), three_values_layout(label)
    for _ in range(20):
        values = _floats(3)
        msg = Float64MultiArray(data=values, layout=MultiArrayLayout(dim=[MultiArrayDimension(label=label, size=3,
                                                                                              stride=3)]))
        _same_wire(template.pack(*values), msg, "std_msgs/msg/Float64MultiArray")
        assert layout.read(serialize_message(msg)) == tuple(values)
    assert layout.read(serialize_message(Float64MultiArray(data=values))) is None  # no layout: decoded elsewhere


def test_joint_states_and_clock():
    joints, clock = joint_template(), CdrTemplate(Clock(), ("clock.sec", "clock.nanosec"))
    for _ in range(20):
        sec, nanosec = _stamp()
        values = _floats(9)
        msg = JointState(name=list(JOINT_NAMES), position=values[:3], velocity=values[3:6],
                         effort=values[6:])
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        _same_wire(joints.pack(sec, nanosec, *values), msg, "sensor_msgs/msg/JointState")
        expected = Clock()
        expected.clock.sec, expected.clock.nanosec = sec, nanosec
        _same_wire(clock.pack(sec, nanosec), expected, "rosgraph_msgs/msg/Clock")


def test_reference_preview():
    _, control = load_params()
    reference = make_reference("paper-circle")
    template = preview_template(control.period_s, control.horizon)
    for t_ns in rng.integers(0, 30 * 10**9, 5).tolist():
        msg = preview_message(reference, t_ns, control.period_s, control.horizon)
        values = preview_values(reference, t_ns, control.period_s, control.horizon)
        assert len(msg.points) == control.horizon + 1
        _same_wire(template.pack(*divmod(t_ns, 10**9), *values), msg, "trajectory_msgs/msg/MultiDOFJointTrajectory")
    assert deserialize_message(template.pack(*divmod(t_ns, 10**9), *values), MultiDOFJointTrajectory).points[
        3].transforms[0].translation.x == values[30]


def test_one_byte_and_integer_fields():
    """Booleans and unsigned integers (few byte values to tell apart) are located too."""
    paths = ("x_offset", "y_offset", "height", "width", "do_rectify")
    template = CdrTemplate(RegionOfInterest(), paths)
    for _ in range(20):
        values = [int(v) for v in rng.integers(0, 2**32, 4)] + [bool(rng.integers(0, 2))]
        msg = RegionOfInterest(**dict(zip(paths, values)))
        _same_wire(template.pack(*values), msg, "sensor_msgs/msg/RegionOfInterest")


@pytest.mark.parametrize("msg, path, reason", [
    (Odometry(), "header.frame_id", "not a fixed-size primitive"),
    (Odometry(), "header.stamp", "not a fixed-size primitive"),
    (Float64MultiArray(data=[1.0]), "data", "is a sequence or array"),
    (Float64MultiArray(data=[1.0]), "data[1]", "beyond the template"),
    (JointState(name=["a"]), "name[0]", "not a fixed-size primitive"),
    (Odometry(), "pose.pose.position.q", "no field 'q'"),
    (Odometry(), "pose.covariance[40]", "beyond the template"),
    (Odometry(), "header.stamp.sec[0]", "not a sequence or array"),
])
def test_variable_length_or_bad_paths_fail_loudly(msg, path, reason):
    with pytest.raises(CdrTemplateError, match=reason):
        CdrTemplate(msg, [path])


def test_repeated_or_missing_paths_and_wrong_value_count_fail_loudly():
    with pytest.raises(CdrTemplateError, match="repeat"):
        CdrTemplate(Clock(), ["clock.sec", "clock.sec"])
    with pytest.raises(CdrTemplateError, match="no field paths"):
        CdrTemplate(Clock(), [])
    template = CdrTemplate(Clock(), ["clock.sec", "clock.nanosec"])
    with pytest.raises(CdrTemplateError, match="1 values for 2"):
        template.pack(1)


def test_template_does_not_change_the_message():
    msg = Float64MultiArray(data=[1.5, 2.5])
    CdrTemplate(msg, ["data[0]", "data[1]"])
    assert msg == Float64MultiArray(data=[1.5, 2.5])


def test_cdr_reader_decodes_odometry_without_importing_rosbags(monkeypatch):
    """The fallback decodes the values rclpy serialized, with rosbags not importable; garbage is MalformedMessage."""
    from robotino_geom_mpc.ros.cdr import MalformedMessage, cdr_reader

    monkeypatch.setitem(sys.modules, "rosbags.typesys", None)  # any import of it fails
    read = cdr_reader(Odometry, "nav_msgs/msg/Odometry")
    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345
    msg.pose.pose.position.x, msg.pose.pose.orientation.w = 0.25, 1.0
    msg.twist.twist.angular.z = -0.5
    got = read(serialize_message(msg))
    assert (got.header.stamp.sec, got.header.stamp.nanosec, got.child_frame_id) == (12, 345, "base_link")
    assert (got.pose.pose.position.x, got.pose.pose.orientation.w, got.twist.twist.angular.z) == (0.25, 1.0, -0.5)
    with pytest.raises(MalformedMessage):
        read(b"\x00\x01\x00\x00\x07")


def _random_odometry(frame: str = "odom", child: str = "base_link") -> Odometry:
    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = frame, child
    msg.header.stamp.sec, msg.header.stamp.nanosec = _stamp()
    p, q, tw = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = _floats(7)
    tw.linear.x, tw.linear.y, tw.angular.z = _floats(3)
    msg.pose.covariance = _floats(36)
    return msg


def test_layout_reads_the_fields_of_any_message_with_the_template_layout():
    """Read in place == rclpy's decoder, for random values, from rclpy's serializer and from the plant's template."""
    layout = messages.odometry_layout()
    for _ in range(20):
        msg = _random_odometry()
        assert layout.read(serialize_message(msg)) == decode.odometry_values(msg)
    plant = CdrTemplate(plant_odometry(0.001, 0.002), ODOM_FIELDS)
    values = (*_stamp(), *_floats(len(ODOM_FIELDS) - 2))
    data = plant.pack(*values)
    assert layout.read(data) == decode.odometry_values(deserialize_message(data, Odometry))


def test_layout_reads_the_preview_of_the_trajectory_node():
    _, control = load_params()
    layout = messages.preview_layout(control.period_s, control.horizon)
    reference = make_reference("lemniscate")
    template = preview_template(control.period_s, control.horizon)
    for t_ns in rng.integers(0, 30 * 10**9, 5).tolist():
        data = template.pack(*divmod(t_ns, 10**9), *preview_values(reference, t_ns, control.period_s, control.horizon))
        msg = TYPESTORE.deserialize_cdr(data, "trajectory_msgs/msg/MultiDOFJointTrajectory")  # a second reader
        assert layout.read(data) == (msg.header.stamp.sec, msg.header.stamp.nanosec,
                                     *decode.preview_point_values(msg, control.horizon))


@pytest.mark.parametrize("change", ["frame", "child", "short", "long", "big_endian"])
def test_layout_refuses_other_layouts(change):
    """Other frame names, truncated or padded bytes, big-endian CDR: None (the caller decodes the general way)."""
    layout = messages.odometry_layout()
    msg = _random_odometry()
    data = serialize_message(msg)
    if change == "frame":
        data = serialize_message(_random_odometry(frame="odox"))  # same length, other bytes
    elif change == "child":
        data = serialize_message(_random_odometry(child="base_footprint"))
    elif change == "short":
        data = data[:-8]
    elif change == "long":
        data = data + bytes(8)
    else:
        data = TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(data, "nav_msgs/msg/Odometry"),
                                       "nav_msgs/msg/Odometry", little_endian=False)
        assert len(data) == layout.size
    assert layout.read(data) is None


def test_layout_of_a_sequence_length_is_checked():
    """A preview with another number of points is refused even where the byte count happens to match."""
    short, long = messages.preview_layout(0.01, 3), messages.preview_layout(0.01, 4)
    template = preview_template(0.01, 4)
    data = template.pack(*range(len(template.paths)))
    assert long.read(data) is not None and short.read(data) is None
    assert short.read(data[: short.size]) is None  # right length, wrong point count


def test_preview_layouts_learn_a_longer_preview_and_try_another_prefix_once(monkeypatch):
    """`PreviewLayouts` (the controller node's): a longer preview's layout is learnt from one general decode and
    reads the next as rosbags does; a preview in another frame prefix is tried once (no layout built again).
    """
    layouts = messages.PreviewLayouts(0.01, 4, "robot1/")
    reference = make_reference("lemniscate")
    longer = preview_template(0.01, 13, "robot1/")
    first, second = (longer.pack(*divmod(t, 10**9), *preview_values(reference, t, 0.01, 13))
                     for t in (2 * 10**9, 2_100_000_000))
    assert layouts.read(first) is None  # not known yet: the general decoder reads it
    layouts.learn(first, 14)
    msg = TYPESTORE.deserialize_cdr(second, "trajectory_msgs/msg/MultiDOFJointTrajectory")
    assert layouts.read(second) == (msg.header.stamp.sec, msg.header.stamp.nanosec,
                                    *decode.preview_point_values(msg, 13))
    foreign = preview_template(0.01, 6, "robot2/")
    other = foreign.pack(*divmod(2 * 10**9, 10**9), *preview_values(reference, 2 * 10**9, 0.01, 6))
    layouts.learn(other, 7)  # its layout in this node's prefix does not read it: remembered as such
    assert layouts.read(other) is None
    built: list = []
    monkeypatch.setattr(messages, "preview_layout", lambda *args: built.append(args))
    layouts.learn(other, 7)  # tried already: no layout is built again
    assert built == [] and layouts.read(other) is None


@pytest.mark.parametrize("frame", ["", "odom", "robot1/odom", "abc"])  # every alignment of the doubles
@pytest.mark.parametrize("n", [0, 1, 2, 7])
def test_path_written_straight_to_cdr_reads_as_the_path_rclpy_builds(frame, n):
    """`messages.path_cdr` against a Path built field by field: rclpy's and rosbags' deserializers agree."""
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path

    rng = np.random.default_rng(n)
    poses = rng.normal(size=(n, 3))
    stamps = [int(s) for s in rng.integers(0, 2**31 * 10**9, size=n)]  # any time a stamp holds
    expected = Path()
    expected.header.frame_id = frame
    expected.header.stamp = messages.ns_to_stamp(123_456_789_012)
    for ns, (x, y, theta) in zip(stamps, poses.tolist()):
        pose = PoseStamped()
        pose.header.frame_id, pose.header.stamp = frame, messages.ns_to_stamp(ns)
        pose.pose.position.x, pose.pose.position.y = x, y
        pose.pose.orientation = messages.yaw_to_quaternion(theta)
        expected.poses.append(pose)
    data = messages.path_cdr(frame, 123_456_789_012, stamps, poses)
    assert deserialize_message(data, Path) == expected
    assert len(data) == len(serialize_message(expected))
    decoded = TYPESTORE.deserialize_cdr(data, "nav_msgs/msg/Path")
    assert [p.header.stamp.sec * 10**9 + p.header.stamp.nanosec for p in decoded.poses] == stamps
    assert [(p.pose.position.x, p.pose.position.y, p.pose.orientation.z, p.pose.orientation.w)
            for p in decoded.poses] == [(p.pose.position.x, p.pose.position.y, p.pose.orientation.z,
                                         p.pose.orientation.w) for p in expected.poses]


@pytest.mark.parametrize("interface", ["voltages", "cmd_vel"])
@pytest.mark.parametrize("length", [1, 25])
def test_plan_writer_gives_the_plan_message_bytes(interface, length):
    """`ros.plans.PlanWriter` against `plan_message` as rclpy serializes it, read back by rclpy and by rosbags."""
    from robotino_geom_mpc.network.plan import CommandPlan
    from robotino_geom_mpc.ros.plans import PlanWriter, plan_message, plan_of_message, plan_type

    rng = np.random.default_rng(length)
    basis = 1_795_768_289.0894086
    plan = CommandPlan(basis, tuple(basis + 0.07 + 0.01 * i for i in range(length)),
                       tuple(tuple(rng.normal(scale=5.0, size=3)) for _ in range(length)), 0.01)
    data = PlanWriter(interface, length).encode(plan)
    msg = deserialize_message(data, plan_type(interface))
    assert msg == plan_message(plan, interface)
    assert plan_of_message(msg, 0.01) == plan_of_message(plan_message(plan, interface), 0.01)
    name = "trajectory_msgs/msg/" + plan_type(interface).__name__
    decoded = TYPESTORE.deserialize_cdr(data, name)
    values = [p.effort.tolist() if interface == "voltages" else
              [p.velocities[0].linear.x, p.velocities[0].linear.y, p.velocities[0].angular.z] for p in decoded.points]
    np.testing.assert_array_equal(values, np.array(plan.entries))
    # a recording's message (rosbags' class, as regress reads it) gives the plan rclpy's gives
    read = plan_of_message(decoded, 0.01)
    np.testing.assert_array_equal(read.entries, np.array(plan.entries))
    assert read == plan_of_message(msg, 0.01)
