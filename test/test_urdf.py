"""The shipped URDF against the parameter files (XML read with xml.etree, geometry computed here) and the generator."""

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file, preset_file
from robotino_geom_mpc.description.urdf import DescriptionError, UrdfJoint, check_frame_prefix, joint_transform, \
    robotino_urdf, urdf_joints

pytestmark = pytest.mark.unit

SHIPPED = Path(__file__).resolve().parents[1] / "urdf" / "robotino.urdf"
BETA = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)  # wheel i at l (cos beta_i, sin beta_i) (ROBOTINO_NOTES)


def _robot_values(path: Path) -> dict:
    return yaml.safe_load(path.read_text())["/**"]["ros__parameters"]["robot"]


def _numbers(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.split()])


def _check_against(urdf: str, robot: dict) -> None:
    """Joints, links and radii of `urdf` against the parameter file's values, read as plain XML."""
    root = ET.fromstring(urdf)
    l, r = robot["wheel_distance_m"], robot["wheel_radius_m"]
    links = {link.get("name"): link for link in root.findall("link")}
    assert set(links) == {"base_link", "wheel0_link", "wheel1_link", "wheel2_link"}
    assert float(links["base_link"].find("visual/geometry/cylinder").get("radius")) == 0.225
    joints = {j.get("name"): j for j in root.findall("joint")}
    assert set(joints) == {"wheel0_joint", "wheel1_joint", "wheel2_joint"}
    for i, beta in enumerate(BETA):
        joint = joints[f"wheel{i}_joint"]
        assert joint.get("type") == "continuous"
        assert joint.find("parent").get("link") == "base_link"
        assert joint.find("child").get("link") == f"wheel{i}_link"
        origin = joint.find("origin")
        np.testing.assert_allclose(_numbers(origin.get("xyz")), [l * math.cos(beta), l * math.sin(beta), r],
                                   atol=1e-9)
        for element in ("visual", "collision"):
            assert float(links[f"wheel{i}_link"].find(f"{element}/geometry/cylinder").get("radius")) == r
        # the axle: the joint axis in base_link is radial, and a positive turn rolls the wheel (centre r
        # above the contact point) along the counter-clockwise tangent, the direction of a positive wheel angle
        axis = Rotation.from_euler("xyz", _numbers(origin.get("rpy"))).apply(_numbers(joint.find("axis").get("xyz")))
        np.testing.assert_allclose(np.cross(axis, [0.0, 0.0, 1.0]), [-math.sin(beta), math.cos(beta), 0.0],
                                   atol=1e-12)


def test_shipped_urdf_is_the_generators_output_for_the_default_preset():
    robot, _ = load_params(default_params_file())
    assert SHIPPED.read_text() == robotino_urdf(robot)


@pytest.mark.parametrize("preset", ["robotino2", "robotino3"])
def test_urdf_agrees_with_the_parameter_file(preset):
    path = preset_file(preset)
    robot, _ = load_params(path)
    _check_against(robotino_urdf(robot), _robot_values(path))


def test_shipped_urdf_agrees_with_the_default_parameter_file():
    _check_against(SHIPPED.read_text(), _robot_values(default_params_file()))


def test_joint_transform_against_scipy():
    rng = np.random.default_rng(3)
    for _ in range(50):
        rpy, xyz = rng.uniform(-math.pi, math.pi, 3), rng.normal(size=3)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        q = float(rng.uniform(-20, 20))
        for kind in ("continuous", "revolute", "fixed"):
            joint = UrdfJoint("j", kind, "a", "b", tuple(xyz), tuple(rpy), tuple(axis))
            translation, quaternion = joint_transform(joint, q)
            expected = Rotation.from_euler("xyz", rpy)  # URDF rpy: fixed axes x, y, z
            if kind != "fixed":
                expected = expected * Rotation.from_rotvec(axis * q)
            np.testing.assert_allclose(translation, xyz)
            assert abs(abs(np.dot(quaternion, expected.as_quat())) - 1.0) < 1e-12


def test_urdf_joints_reads_the_shipped_file_and_refuses_bad_urdf():
    robot, _ = load_params()
    joints = urdf_joints(SHIPPED.read_text())
    assert [(j.name, j.type, j.parent, j.child) for j in joints] == [
        (f"wheel{i}_joint", "continuous", "base_link", f"wheel{i}_link") for i in range(3)]
    for bad, words in [("<robot", "not XML"), ("<model/>", "<robot>"),
                       ('<robot><joint name="j" type="fixed"><child link="a"/></joint></robot>', "parent"),
                       ('<robot><joint name="j"><parent link="a"/><child link="b"/><axis xyz="0 0 0"/></joint>'
                        "</robot>", "zero axis"),
                       ('<robot><joint name="j"><parent link="a"/><child link="b"/><origin xyz="1 nan 0"/></joint>'
                        "</robot>", "finite")]:
        with pytest.raises(DescriptionError, match=words):
            urdf_joints(bad)


@pytest.mark.parametrize("prefix", ["", "robot1/", "fleet/robot_2/"])
def test_valid_frame_prefixes(prefix):
    assert check_frame_prefix(prefix) == prefix


@pytest.mark.parametrize("prefix", ["robot1", "/robot1/", "1robot/", "robot 1/", "robot1//", "a/b"])
def test_invalid_frame_prefixes(prefix):
    with pytest.raises(DescriptionError, match="frame prefix"):
        check_frame_prefix(prefix)
