"""The plant's measurement messages: odometry templates, the wheels on ``joint_states``, odom -> base_link on /tf.

The odometry (`odometry_template`, `odometry_values`): frames ``<frame_prefix>odom`` -> child
``<frame_prefix>base_link``, pose variance from the noise settings, z/roll/pitch certain, the twist certain
(ideal) or with the encoders' bound (`encoders.twist_covariance`). The encoders' pose is dead reckoning
whose drift grows with the path: its covariance does not follow it (fuse the twist, as robot_localization
advises for wheel odometry).

``joint_states`` (sensor_msgs/JointState, when ``publish_joint_states``): joints ``wheel0_joint`` ..
``wheel2_joint`` of the URDF (`description.urdf`): angle [rad] (rim distance / r integrated by the plant,
positive rolling along the wheel's rolling direction), angular velocity [rad/s], effort = wheel torque gear
Km i [N m].

``/tf`` (tf2_msgs/TFMessage, when ``publish_tf``): ``<frame_prefix>odom`` -> ``<frame_prefix>base_link``,
the pose the odometry message of the same tick carries, with its stamp, as the Robotino drivers publish
it. The topic is absolute, as tf2 listens (a node namespace does not move it): several robots in one
domain keep their frames apart by ``frame_prefix`` (``robot1/``), as robot_state_publisher's parameter
of that name does. Without tf2_msgs (a venv where ``make setup`` did not build it) one error line says
so and the plant runs without /tf.

``applied_voltages`` (std_msgs/Float64MultiArray, 3 values [V], layout label ``wheel_voltage_v`` as
``wheel_voltages``; ``command_interface`` cmd_vel only, `AppliedVoltages`): per drive the mean voltage the
wheel-speed PI loops applied over the period the currents of ``wheel_currents`` cover (what
`simulation.run_scenario` records as a cmd_vel run's voltages), published just before those currents.

`PlantOutputs` holds every publisher of the plant node and turns what the robot loop measures
(`loop.robot_loop.Measurement`, its truth and joints) into the messages of a tick, in their order: odom (then
/clock in lockstep), the currents of the period just integrated (``applied_voltages`` just before them), the
ground truth, /tf, the joints; the optional ones only while a subscription is matched. The messages are pairs
(publisher, bytes): published at once, or put on the emulated link as one packet.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory

from robotino_geom_mpc.params.specs import ParamSpec
from robotino_geom_mpc.description.urdf import BASE_LINK, JOINT_NAMES, check_frame_prefix
from robotino_geom_mpc.ros.cdr import CdrTemplate
from robotino_geom_mpc.ros.decode import STAMP_FIELDS
from robotino_geom_mpc.loop.robot_loop import Measurement, RobotLoop
from robotino_geom_mpc.model.encoders import twist_covariance
from robotino_geom_mpc.params.specs import RobotinoParams
from robotino_geom_mpc.ros.messages import CURRENT_LABEL, ODOM_FRAME, VOLTAGE_LABEL, odometry_message, \
    three_values_template, yaw_quaternion_zw
from robotino_geom_mpc.ros.qos import publish_acknowledged

__all__ = ["Message", "ODOM_FIELDS", "PlantOutputs", "TF_DEFAULTS", "TF_SPECS", "joint_template", "odometry_template",
           "odometry_values", "plant_odometry"]

Message = tuple[Publisher, Any]
"""A message of a tick: its publisher and its bytes (or message)."""

TF_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("publish_tf", bool, "Publish odom -> base_link (the odometry's pose) on /tf, as the drivers do"),
    ParamSpec("frame_prefix", str, "Prefix of the frame ids odom and base_link (odometry, /tf), e.g. 'robot1/' "
              "for several robots in one domain; empty: none"),
    ParamSpec("publish_joint_states", bool, "Publish the wheels' angles, speeds and torques on joint_states (what "
              "a robot description's wheel frames follow; the report does not read them)"),
)
TF_DEFAULTS = {"publish_tf": True, "frame_prefix": "", "publish_joint_states": True}

# variance for the planar-motion axes (z, roll, pitch known to be 0) and for noise-free quantities
_CERTAIN = 1e-12
_PLANAR = [0, 1, 5]  # x, y and yaw in a 6x6 covariance

ODOM_FIELDS = STAMP_FIELDS + (
    "pose.pose.position.x", "pose.pose.position.y", "pose.pose.orientation.z", "pose.pose.orientation.w",
    "twist.twist.linear.x", "twist.twist.linear.y", "twist.twist.angular.z",
)

_TF_FIELDS = tuple(f"transforms[0].{field}" for field in STAMP_FIELDS + (
    "transform.translation.x", "transform.translation.y", "transform.rotation.z", "transform.rotation.w"))


def plant_odometry(sigma_position: float, sigma_yaw: float, frame_prefix: str = "",
                   twist_covariance: np.ndarray | None = None) -> Odometry:
    """The plant's Odometry, values zero: frames and covariances set (pose variance from the noise,
    z/roll/pitch certain: planar; the twist's (3, 3) covariance of v_x, v_y, omega, None: noise-free).
    """
    msg = odometry_message(frame_prefix)
    pose_var = (max(sigma_position**2, _CERTAIN),) * 2 + (_CERTAIN,) * 3 + (max(sigma_yaw**2, _CERTAIN),)
    msg.pose.covariance = np.diag(pose_var).ravel()
    twist = np.diag([_CERTAIN] * 6)
    if twist_covariance is not None:
        twist[np.ix_(_PLANAR, _PLANAR)] = twist_covariance
    msg.twist.covariance = twist.ravel()
    return msg


def odometry_template(sigma_position: float, sigma_yaw: float, frame_prefix: str,
                      twist_covariance: np.ndarray | None = None) -> CdrTemplate:
    """`plant_odometry` as a template of `ODOM_FIELDS` (values: stamp, then `odometry_values`)."""
    return CdrTemplate(plant_odometry(sigma_position, sigma_yaw, frame_prefix, twist_covariance), ODOM_FIELDS)


def odometry_values(pose: tuple[float, ...], twist_body: tuple[float, ...]) -> tuple[float, ...]:
    """The values of `odometry_template` after the stamp: x, y, yaw quaternion (z, w), body twist (vx, vy, omega)."""
    x, y, theta = pose
    return (x, y, *yaw_quaternion_zw(theta), *twist_body)


def joint_template() -> CdrTemplate:
    """JointState of the three wheels: stamp, then position, velocity and effort of wheels 0..2."""
    joints = JointState(name=list(JOINT_NAMES), position=[0.0] * 3, velocity=[0.0] * 3, effort=[0.0] * 3)
    return CdrTemplate(joints, STAMP_FIELDS + tuple(
        f"{field}[{j}]" for field in ("position", "velocity", "effort") for j in range(3)))


class PlantOutputs:
    """Every publisher of the plant node and the messages of a tick (module docstring).

    Parameters
    ----------
    node
        The plant node.
    qos
        The writers' QoS (`ros.qos.publish_qos`).
    params
        The node's parameter values (``publish_tf``, ``publish_joint_states``, ``frame_prefix``,
        ``odometry_noise.*``, ``odometry_model``, ``encoder.*``).
    lockstep
        /clock is published.
    cmd_vel
        ``applied_voltages`` is published.
    reports
        ``command_applied`` is published (plans).
    """

    def __init__(self, node: Node, qos: QoSProfile, params: Any, lockstep: bool, cmd_vel: bool,
                 reports: bool) -> None:
        self.node = node
        self.frame_prefix = check_frame_prefix(params["frame_prefix"])
        self.odom_frame, self.base_frame = self.frame_prefix + ODOM_FRAME, self.frame_prefix + BASE_LINK
        self.odom_pub = node.create_publisher(Odometry, "odom", qos)
        self.truth_pub = node.create_publisher(Odometry, "ground_truth/odom", qos)
        self.current_pub = node.create_publisher(Float64MultiArray, "wheel_currents", qos)
        self.joint_pub = node.create_publisher(JointState, "joint_states", qos) \
            if params["publish_joint_states"] else None
        self.tf_pub: Publisher | None = None
        self.tf_cdr: CdrTemplate | None = None
        if params["publish_tf"]:
            message = self._tf_message()
            if message is not None:
                self.tf_pub = node.create_publisher(type(message), "/tf", qos)
                self.tf_cdr = CdrTemplate(message, _TF_FIELDS)
        self.clock_pub = node.create_publisher(ClockMsg, "/clock", qos) if lockstep else None
        self.applied_pub = node.create_publisher(Float64MultiArray, "applied_voltages", qos) if cmd_vel else None
        self.report_pub = node.create_publisher(JointTrajectory, "command_applied", qos) if reports else None
        self.joint_cdr = joint_template()
        self.current_cdr = three_values_template(CURRENT_LABEL)
        self.voltage_cdr = three_values_template(VOLTAGE_LABEL)
        self.clock_cdr = CdrTemplate(ClockMsg(), ("clock.sec", "clock.nanosec"))

    def build(self, params: Any, robot: RobotinoParams, period_s: float) -> None:
        """The odometry templates (frames, covariances from the noise and the odometry model) for `params`."""
        twist = None if params["odometry_model"] == "ideal" else twist_covariance(
            robot, params["encoder.counts_per_rev"], params["encoder.wheel_slip_std"], period_s)
        self.odom_cdr = odometry_template(params["odometry_noise.position_m"], params["odometry_noise.yaw_rad"],
                                          self.frame_prefix, twist)
        self.truth_cdr = odometry_template(0.0, 0.0, self.frame_prefix)

    def publishers(self) -> dict[str, Publisher | None]:
        """The publishers by topic (the lockstep start handshake counts their readers)."""
        return {"odom": self.odom_pub, "ground_truth/odom": self.truth_pub, "wheel_currents": self.current_pub,
                "joint_states": self.joint_pub, "/tf": self.tf_pub, "/clock": self.clock_pub,
                "clock": self.clock_pub, "applied_voltages": self.applied_pub, "command_applied": self.report_pub}

    def odometry(self, m: Measurement) -> Message:
        """The odometry message of `m`."""
        return self.odom_pub, self.odom_cdr.pack(*divmod(m.stamp_ns, 1_000_000_000), *odometry_values(m.pose, m.twist))

    def clock(self, stamp_ns: int) -> Message:
        """/clock at `stamp_ns` (lockstep)."""
        assert self.clock_pub is not None
        return self.clock_pub, self.clock_cdr.pack(*divmod(stamp_ns, 1_000_000_000))

    def period(self, currents: tuple[float, ...] | None, voltages: tuple[float, ...] | None) -> list[Message]:
        """What the drives did over the period just integrated: ``applied_voltages`` then ``wheel_currents``."""
        out: list[Message] = []
        if voltages is not None and self.applied_pub is not None and self.applied_pub.get_subscription_count():
            out.append((self.applied_pub, self.voltage_cdr.pack(*voltages)))
        if currents is not None and self.current_pub.get_subscription_count():
            out.append((self.current_pub, self.current_cdr.pack(*currents)))
        return out

    def state(self, stamp_ns: int, robot: RobotLoop, pose: tuple[float, ...]) -> list[Message]:
        """Ground truth, /tf (odom -> base_link at `pose`, the odometry's) and the joints at `stamp_ns`."""
        stamp, out = divmod(stamp_ns, 1_000_000_000), []
        if self.truth_pub.get_subscription_count():
            out.append((self.truth_pub, self.truth_cdr.pack(*stamp, *odometry_values(*robot.truth()))))
        if self.tf_pub is not None and self.tf_cdr is not None and self.tf_pub.get_subscription_count():
            x, y, theta = pose
            out.append((self.tf_pub, self.tf_cdr.pack(*stamp, x, y, *yaw_quaternion_zw(theta))))
        if self.joint_pub is not None and self.joint_pub.get_subscription_count():
            angles, speeds, torques = robot.joints()
            out.append((self.joint_pub, self.joint_cdr.pack(*stamp, *angles, *speeds, *torques)))
        return out

    def tick(self, m: Measurement, robot: RobotLoop, clock: bool = False) -> list[Message]:
        """The messages of a fresh measurement in order: odom, (/clock), the period's voltages and currents, the
        ground truth, /tf, the joints.
        """
        return [self.odometry(m), *([self.clock(m.stamp_ns)] if clock else []),
                *self.period(m.currents, m.applied_voltages), *self.state(m.stamp_ns, robot, m.pose)]

    def publish(self, messages: list[Message]) -> None:
        """Publish `messages` in order (a full keep-all history waits for its readers, `publish_acknowledged`)."""
        for pub, data in messages:
            publish_acknowledged(self.node, pub, data)

    def _tf_message(self) -> Any:
        """A TFMessage with one transform odom -> base_link (frames set); None, logged, without tf2_msgs."""
        try:
            from geometry_msgs.msg import TransformStamped
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.node.get_logger().error("tf2_msgs is not installed: no /tf (in a venv, 'make setup' builds it)")
            return None
        transform = TransformStamped(child_frame_id=self.base_frame)
        transform.header.frame_id = self.odom_frame
        return TFMessage(transforms=[transform])
