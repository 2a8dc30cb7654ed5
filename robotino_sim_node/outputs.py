"""The plant's measurement messages: odometry templates, the wheels on ``joint_states``, odom -> base_link on /tf.

The odometry (`odometry_template`, `odometry_values`): frames ``<frame_prefix>odom`` -> child
``<frame_prefix>base_link``, pose variance from the noise settings, z/roll/pitch certain, the twist certain
(ideal) or with the encoders' bound (`encoders.twist_covariance`). The encoders' pose is dead reckoning
whose drift grows with the path: its covariance does not follow it (fuse the twist, as robot_localization
advises for wheel odometry).

``joint_states`` (sensor_msgs/JointState): joints ``wheel0_joint`` .. ``wheel2_joint`` of the URDF
(`description.urdf`): angle [rad] (rim distance / r integrated by the plant, positive rolling along the
wheel's rolling direction), angular velocity [rad/s], effort = wheel torque gear Km i [N m].

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

All go out only while a subscription is matched, with the plant's other publishers' QoS, through the writer's
``send(publisher, message)`` (`publish_acknowledged` by default; the plant's link replaces it).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from robotino_geom_mpc.params.specs import ParamSpec
from robotino_geom_mpc.description.urdf import BASE_LINK, JOINT_NAMES, check_frame_prefix
from robotino_geom_mpc.ros.cdr import CdrTemplate
from robotino_geom_mpc.ros.decode import STAMP_FIELDS
from robotino_geom_mpc.ros.messages import ODOM_FRAME, VOLTAGE_LABEL, odometry_message, three_values_template, \
    yaw_quaternion_zw
from robotino_geom_mpc.ros.qos import publish_acknowledged

__all__ = ["AppliedVoltages", "ODOM_FIELDS", "TF_DEFAULTS", "TF_SPECS", "StateOutputs", "joint_template",
           "odometry_template", "odometry_values", "plant_odometry"]

TF_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("publish_tf", bool, "Publish odom -> base_link (the odometry's pose) on /tf, as the drivers do"),
    ParamSpec("frame_prefix", str, "Prefix of the frame ids odom and base_link (odometry, /tf), e.g. 'robot1/' "
              "for several robots in one domain; empty: none"),
)
TF_DEFAULTS = {"publish_tf": True, "frame_prefix": ""}

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


class StateOutputs:
    """Publishers of ``joint_states`` and ``/tf`` of a plant node (see the module docstring).

    Parameters
    ----------
    node
        The plant node.
    qos
        The writers' QoS (`ros.qos.publish_qos`).
    publish_tf
        Whether /tf goes out.
    frame_prefix
        Validated (`description.urdf.check_frame_prefix`; a `DescriptionError` otherwise).
    """

    def __init__(self, node: Node, qos: QoSProfile, publish_tf: bool, frame_prefix: str) -> None:
        self.node = node
        self.send = lambda pub, message: publish_acknowledged(node, pub, message)
        self.odom_frame = check_frame_prefix(frame_prefix) + ODOM_FRAME
        self.base_frame = frame_prefix + BASE_LINK
        self.joint_pub = node.create_publisher(JointState, "joint_states", qos)
        self.joint_cdr = joint_template()
        self.tf_pub = self.tf_cdr = None
        if publish_tf:
            message = self._tf_message()
            if message is not None:
                self.tf_pub = node.create_publisher(type(message), "/tf", qos)
                self.tf_cdr = CdrTemplate(message, _TF_FIELDS)

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

    def publish(self, stamp: tuple[int, int], pose: tuple[float, float, float], wheel_angles: list[float],
                wheel_speeds: list[float], wheel_torques: list[float]) -> None:
        """Publish /tf (``pose`` x, y, yaw of the odometry) and the joints, stamped `stamp` (sec, nanosec)."""
        if self.tf_pub is not None and self.tf_pub.get_subscription_count():
            x, y, theta = pose
            self.send(self.tf_pub, self.tf_cdr.pack(*stamp, x, y, *yaw_quaternion_zw(theta)))
        if self.joint_pub.get_subscription_count():
            self.send(self.joint_pub, self.joint_cdr.pack(*stamp, *wheel_angles, *wheel_speeds, *wheel_torques))


class AppliedVoltages:
    """``applied_voltages`` of a cmd_vel plant: the time mean of the PI loops' held voltages since the last publish.

    Parameters
    ----------
    node
        The plant node.
    qos
        The writers' QoS (`ros.qos.publish_qos`).
    """

    def __init__(self, node: Node, qos: QoSProfile) -> None:
        self.node = node
        self.send = lambda pub, message: publish_acknowledged(node, pub, message)
        self.pub = node.create_publisher(Float64MultiArray, "applied_voltages", qos)
        self.cdr = three_values_template(VOLTAGE_LABEL)
        self.volt_seconds = np.zeros(3)
        self.seconds = 0.0

    def drive(self, loop: Any, plant: Any, twist_body: tuple[float, ...], duration_s: float) -> np.ndarray:
        """Run `loop` (a `wheel_speed_loop.WheelSpeedLoop`) on `plant` for `duration_s` towards `twist_body`,
        account the voltages it held; returns each drive's peak |armature current| [A] over that time.
        """
        held, currents = loop.run(plant, twist_body, duration_s)
        self.volt_seconds += held.mean(axis=0) * duration_s
        self.seconds += duration_s
        return np.abs(currents).max(axis=0)

    def publish(self) -> None:
        """Publish the mean since the last publish (if a reader is matched and time has passed), then restart it."""
        if self.seconds > 0.0 and self.pub.get_subscription_count():
            self.send(self.pub, self.cdr.pack(*(self.volt_seconds / self.seconds).tolist()))
        self.volt_seconds = np.zeros(3)
        self.seconds = 0.0
