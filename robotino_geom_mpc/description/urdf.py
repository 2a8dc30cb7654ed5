"""The Robotino's URDF from `RobotinoParams`, its joints read back, and the frame-id prefix rule.

The model (REP-103 axes, REP-105 frame names) is what RViz and Foxglove draw:

* ``base_link`` on the floor under the robot's centre, with a cylinder of the body (`BASE_RADIUS_M`) drawn
  above the wheels;
* ``wheel0_link`` .. ``wheel2_link``, cylinders of the wheel radius r, on continuous joints
  ``wheel0_joint`` .. ``wheel2_joint`` at the wheels' positions `model.dynamics.wheel_positions` (eq. 9's
  l, beta_i = -phi_i), the wheel centre r above the floor. Each joint frame is turned by beta_i (its x
  axis points away from the centre) and turns about -x, the axle pointing inwards, so that a positive
  joint angle rolls the wheel along its rolling direction d_i(0) (`model.dynamics.wheel_rolling_directions`),
  the sign of the plant's wheel angles (angular velocity -x turns the contact-to-centre lever r z into a
  centre velocity r (-x) x z = r y = d_i(0)).
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.model.dynamics import wheel_positions
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = [
    "BASE_LINK", "BASE_RADIUS_M", "JOINT_NAMES", "WHEEL_LINKS", "DescriptionError", "UrdfJoint",
    "check_frame_prefix", "joint_transform", "robotino_urdf", "urdf_joints",
]

BASE_LINK = "base_link"
JOINT_NAMES = ("wheel0_joint", "wheel1_joint", "wheel2_joint")
WHEEL_LINKS = ("wheel0_link", "wheel1_link", "wheel2_link")
BASE_RADIUS_M = 0.225  # Robotino 3/4 body: public Robotino 3/4 URDFs (docs/robotino.md, "Parameters and their sources")
BASE_HEIGHT_M = 0.16  # visual only
BASE_GAP_M = 0.01  # body bottom above the wheels' tops, so that the wheels show below it (visual only)
WHEEL_WIDTH_M = 0.03  # visual only

_PREFIX = re.compile(r"(?:[A-Za-z_][A-Za-z0-9_]*/)*")


class DescriptionError(RobotinoError, ValueError):
    """A frame prefix or URDF the description cannot use."""


def check_frame_prefix(prefix: str) -> str:
    """`prefix` if it is a valid frame-id prefix: empty, or names ending in ``/`` (``robot1/``, ``a/b/``).

    Raises
    ------
    DescriptionError
        Naming the prefix and the rule (tf2 frame ids have no leading ``/``).
    """
    if not _PREFIX.fullmatch(prefix):
        raise DescriptionError(
            f"frame prefix {prefix!r}: need '' or names of letters, digits and underscores (not starting with "
            "a digit), each followed by '/', e.g. 'robot1/' (no leading '/')")
    return prefix


def _f(*values: float) -> str:
    return " ".join(f"{v + 0.0:.12g}" for v in values)  # + 0.0: no "-0"


def robotino_urdf(p: RobotinoParams, name: str = "robotino") -> str:
    """The URDF of the Robotino with the geometry of `p` (see the module docstring), as XML text."""
    robot = ET.Element("robot", name=name)
    for material, rgba in (("body", "0.85 0.85 0.85 1"), ("wheel", "0.15 0.15 0.15 1")):
        ET.SubElement(ET.SubElement(robot, "material", name=material), "color", rgba=rgba)
    base = ET.SubElement(robot, "link", name=BASE_LINK)
    _cylinder(base, BASE_RADIUS_M, BASE_HEIGHT_M, _f(0, 0, 2 * p.r + BASE_GAP_M + BASE_HEIGHT_M / 2), "0 0 0", "body")
    for joint_name, link_name, (x, y) in zip(JOINT_NAMES, WHEEL_LINKS, wheel_positions(p)):
        wheel = ET.SubElement(robot, "link", name=link_name)
        _cylinder(wheel, p.r, WHEEL_WIDTH_M, "0 0 0", _f(0, math.pi / 2, 0), "wheel")  # axis z turned onto x
        joint = ET.SubElement(robot, "joint", name=joint_name, type="continuous")
        ET.SubElement(joint, "parent", link=BASE_LINK)
        ET.SubElement(joint, "child", link=link_name)
        ET.SubElement(joint, "origin", xyz=_f(x, y, p.r), rpy=_f(0, 0, math.atan2(y, x)))
        ET.SubElement(joint, "axis", xyz="-1 0 0")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _cylinder(link: ET.Element, radius: float, length: float, xyz: str, rpy: str, material: str) -> None:
    """A visual and a collision cylinder of `link` at (`xyz`, `rpy`)."""
    for tag in ("visual", "collision"):
        element = ET.SubElement(link, tag)
        ET.SubElement(element, "origin", xyz=xyz, rpy=rpy)
        ET.SubElement(ET.SubElement(element, "geometry"), "cylinder", radius=_f(radius), length=_f(length))
        if tag == "visual":
            ET.SubElement(element, "material", name=material)


@dataclass(frozen=True)
class UrdfJoint:
    """A URDF joint: type, parent and child link, origin (xyz [m], rpy [rad]), unit axis."""

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]


def urdf_joints(text: str) -> list[UrdfJoint]:
    """The joints of a URDF (defaults as in the URDF spec: origin zero, axis x).

    Raises
    ------
    DescriptionError
        For text that is not a URDF, a joint without parent/child, malformed numbers or a zero axis.
    """
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise DescriptionError(f"URDF is not XML: {exc}") from None
    if root.tag != "robot":
        raise DescriptionError(f"URDF root element is <{root.tag}>, not <robot>")
    joints = []
    for element in root.iter("joint"):
        name = element.get("name", "")
        parent, child, origin, axis = (element.find(tag) for tag in ("parent", "child", "origin", "axis"))
        if parent is None or child is None:
            raise DescriptionError(f"URDF joint {name!r} needs <parent> and <child>")
        vector = np.array(_numbers(axis.get("xyz", "1 0 0") if axis is not None else "1 0 0", name))
        if not np.linalg.norm(vector) > 0:
            raise DescriptionError(f"URDF joint {name!r}: zero axis")
        origin_attr = origin.attrib if origin is not None else {}
        joints.append(UrdfJoint(
            name, element.get("type", ""), parent.get("link", ""), child.get("link", ""),
            _numbers(origin_attr.get("xyz", "0 0 0"), name), _numbers(origin_attr.get("rpy", "0 0 0"), name),
            tuple((vector / np.linalg.norm(vector)).tolist()),
        ))
    return joints


def _numbers(text: str, joint: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        values = ()
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise DescriptionError(f"URDF joint {joint!r}: need three finite numbers, got {text!r}")
    return values


def _quaternion_product(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Hamilton product a b of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def _axis_angle(axis: tuple[float, float, float], angle: float) -> tuple[float, float, float, float]:
    s = math.sin(0.5 * angle)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(0.5 * angle))


def joint_transform(joint: UrdfJoint, position: float = 0.0) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Parent -> child transform of `joint` at `position` [rad] as (translation xyz, quaternion xyzw).

    The URDF's convention (as robot_state_publisher computes it): the origin (xyz, then the fixed-axis
    roll-pitch-yaw R = Rz(yaw) Ry(pitch) Rx(roll)) followed by the rotation about the joint axis by
    `position` (revolute and continuous joints; a fixed joint ignores `position`).
    """
    roll, pitch, yaw = joint.rpy
    rotation = _quaternion_product(_quaternion_product(_axis_angle((0.0, 0.0, 1.0), yaw),
                                                       _axis_angle((0.0, 1.0, 0.0), pitch)),
                                   _axis_angle((1.0, 0.0, 0.0), roll))
    if joint.type in ("revolute", "continuous"):
        rotation = _quaternion_product(rotation, _axis_angle(joint.axis, position))
    return joint.xyz, rotation
