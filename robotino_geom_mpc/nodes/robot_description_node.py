"""Robot description publisher: the Robotino's URDF and its wheels' TF (a minimal robot_state_publisher).

Where robot_state_publisher is not installed (``robotino-geom-mpc run``, pip installs) this node does its
job for the package's robot; the launch file uses robot_state_publisher where it is.

Topics (relative names)
-----------------------
publishes  ``robot_description``  std_msgs/String, the URDF generated from the robot parameters
                                  (`description.urdf.robotino_urdf`; ``urdf/robotino.urdf`` for the default
                                  preset), reliable, transient local, depth 1: a late subscriber (RViz,
                                  a recorder) gets it; again after a robot parameter changes
           ``/tf``                tf2_msgs/TFMessage: per ``joint_states`` message, parent -> child of every
                                  revolute/continuous joint it names (`description.urdf.joint_transform`),
                                  with its stamp
           ``/tf_static``         the fixed joints, once (transient local; the Robotino has none)
subscribes ``joint_states``       sensor_msgs/JointState (the plant's wheels)

QoS of joint_states and /tf (reliable, volatile) follow ``mode`` as the loop's writers do (`ros.qos.publish_qos`):
realtime keep-last 100 (a reader more than 100 messages behind loses some; the node never waits), lockstep
keep-all on both, each /tf published with `ros.qos.publish_acknowledged`: every tick's wheel transforms reach a
recorder, and a slow reader holds the plant back through this node instead of losing messages (under a busy
core a keep-last /tf lost 241 of a 20 s run's 2000 wheel transforms).

Frame ids are the URDF's links with ``frame_prefix`` (as robot_state_publisher's parameter of that name).
A joint_states message naming exactly the moving joints in the URDF's order (the plant's) is read in place
and its /tf patched into a serialized template (`ros.cdr`: no Python message per tick); any other goes
through the general decoder and the same transforms as messages. A joint_states message whose names and
positions do not pair up, or with a non-finite position, is skipped with a throttled warning; names the URDF
does not have are ignored.

Parameters: the robot/control parameters of config/*.yaml (``/**`` section) plus ``frame_prefix`` and ``mode``.
"""

from __future__ import annotations

import math
from typing import Any

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from builtin_interfaces.msg import Time as TimeMsg

from robotino_geom_mpc.params.specs import ALL_SPECS, ParamSpec
from robotino_geom_mpc.description.urdf import DescriptionError, check_frame_prefix, joint_transform, \
    robotino_urdf, urdf_joints
from robotino_geom_mpc.ros.cdr import CdrLayout, CdrTemplate, MalformedMessage, cdr_reader
from robotino_geom_mpc.ros.decode import STAMP_FIELDS
from robotino_geom_mpc.ros.parameters import NodeStartError, SpecParameters, spec_defaults
from robotino_geom_mpc.ros.qos import LATCHED_QOS, publish_acknowledged, publish_qos
from robotino_geom_mpc.ros.spin import run_node
from robotino_geom_mpc.ros.throttle import warn_throttled

__all__ = ["DESCRIPTION_SPECS", "RobotDescriptionNode", "main"]

DESCRIPTION_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("frame_prefix", str, "Prefix of the frame ids (the URDF's links), e.g. 'robot1/'; empty: none"),
    ParamSpec("mode", str, "realtime: joint_states and /tf keep-last 100 (never waits); lockstep: keep-all, every "
              "wheel transform reaches a recorder (a slow reader holds the loop back)",
              choices=("realtime", "lockstep")),
)
_MOVING = ("revolute", "continuous")
_ROTATION = ("x", "y", "z", "w")


def _prefix_problem(values: dict[str, Any]) -> str | None:
    try:
        check_frame_prefix(values["frame_prefix"])
    except DescriptionError as exc:
        return f"parameter 'frame_prefix': {exc}"
    return None


class RobotDescriptionNode(Node):
    """The robot description publisher (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__("robot_description_publisher")
        from geometry_msgs.msg import TransformStamped
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            raise NodeStartError("tf2_msgs is not installed (in a venv, 'make setup' builds it)") from None

        self._transform, self._tf_message = TransformStamped, TFMessage
        self.params = SpecParameters(self, ALL_SPECS + DESCRIPTION_SPECS,
                                     {**spec_defaults(), "frame_prefix": "", "mode": "realtime"},
                                     self._on_params, check=_prefix_problem, fixed=("mode",))
        qos = publish_qos(self.params["mode"] == "lockstep")
        self.description_pub = self.create_publisher(String, "robot_description", LATCHED_QOS)
        self.tf_pub = self.create_publisher(TFMessage, "/tf", qos)
        self.static_pub = self.create_publisher(TFMessage, "/tf_static", LATCHED_QOS)  # as tf2's static broadcaster
        self.skipped = 0
        self._read_joints = cdr_reader(JointState, "sensor_msgs/msg/JointState")
        self._describe()
        self.create_subscription(JointState, "joint_states", self._on_joint_bytes, qos, raw=True)
        self.get_logger().info(f"robot description published ({len(self.moving)} moving joints)")

    def _on_params(self, changed: dict) -> None:
        self._describe()

    def _describe(self) -> None:
        """Generate the URDF of the current parameters; publish it and the fixed joints."""
        robot, _ = self.params.robot_control()
        self.urdf = robotino_urdf(robot)
        joints = urdf_joints(self.urdf)
        self.moving = {j.name: j for j in joints if j.type in _MOVING}
        self._templates()
        self.description_pub.publish(String(data=self.urdf))
        fixed = [j for j in joints if j.type == "fixed"]
        if fixed:
            stamp = self.get_clock().now().to_msg()
            self.static_pub.publish(self._tf_message(transforms=[self._stamped(j, 0.0, stamp) for j in fixed]))

    def _stamped(self, joint, position: float, stamp) -> Any:
        """The TransformStamped parent -> child of `joint` at `position`, frames prefixed."""
        prefix = self.params["frame_prefix"]
        (x, y, z), (qx, qy, qz, qw) = joint_transform(joint, position)
        msg = self._transform(child_frame_id=prefix + joint.child)
        msg.header.stamp, msg.header.frame_id = stamp, prefix + joint.parent
        t, r = msg.transform.translation, msg.transform.rotation
        t.x, t.y, t.z, r.x, r.y, r.z, r.w = x, y, z, qx, qy, qz, qw
        return msg

    def _templates(self) -> None:
        """The in-place reader of joint_states naming the moving joints in order, and their /tf as a template."""
        n = len(self.moving)
        names = list(self.moving)
        self.joint_layout = CdrLayout(
            JointState(name=names, position=[0.0] * n, velocity=[0.0] * n, effort=[0.0] * n),
            STAMP_FIELDS + tuple(f"position[{j}]" for j in range(n)))
        stamp = TimeMsg()
        message = self._tf_message(transforms=[self._stamped(self.moving[name], 0.0, stamp) for name in names])
        self.tf_cdr = CdrTemplate(message, tuple(
            f"transforms[{j}].{field}" for j in range(n) for field in STAMP_FIELDS + tuple(
                f"transform.rotation.{axis}" for axis in _ROTATION)))

    def _on_joint_bytes(self, data: bytes) -> None:
        """joint_states as bytes: the plant's layout read in place, /tf from the template; else decoded."""
        values = self.joint_layout.read(data)
        if values is None:
            try:
                msg = self._read_joints(data)
            except MalformedMessage as exc:
                self.skipped += 1
                warn_throttled(self.get_logger(),
                               f"undecodable joint_states: skipped ({self.skipped} so far): {exc}", 2.0)
                return
            self._on_joints(msg)
            return
        stamp, positions = values[:2], values[2:]
        if not math.isfinite(sum(positions)):
            self._skip(len(positions), len(positions))
            return
        publish_acknowledged(self, self.tf_pub, self.tf_cdr.pack(*(
            value for joint, position in zip(self.moving.values(), positions)
            for value in (*stamp, *joint_transform(joint, position)[1]))))

    def _skip(self, names: int, positions: int) -> None:
        self.skipped += 1
        warn_throttled(self.get_logger(), f"joint_states with {names} names, {positions} positions or a non-finite "
            f"position: skipped ({self.skipped} so far)", 2.0)

    def _on_joints(self, msg: JointState) -> None:
        """A decoded joint_states (any names, order, length): the transforms of the moving joints it names."""
        if len(msg.name) != len(msg.position) or not all(map(math.isfinite, msg.position)):
            self._skip(len(msg.name), len(msg.position))
            return
        transforms = [self._stamped(self.moving[name], position, msg.header.stamp)
                      for name, position in zip(msg.name, msg.position) if name in self.moving]
        if transforms:
            publish_acknowledged(self, self.tf_pub, self._tf_message(transforms=transforms))


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc robot_description_publisher``."""
    return run_node(RobotDescriptionNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
