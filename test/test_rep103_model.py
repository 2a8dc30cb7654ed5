"""The robot model in REP-103 frames (erratum 6): the wheel directions turn with the robot.

Truths used: a rigid body with the wheels at `wheel_positions` pushing along their rolling directions
(2-D cross products written out here), the body-frame acceleration's independence of the heading, the
plant integrated step by step, and the no-slip contact velocity v + omega x p_i of each wheel.
"""

import pytest
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.model import dynamics as model
from robotino_geom_mpc.geometric.decoupling import DecouplingField
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.model.encoders import EncoderOdometry
from robotino_geom_mpc.model.plant import RobotinoPlant

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params()
TS = CONTROL.period_s

angles = st.floats(-4.0 * math.pi, 4.0 * math.pi, allow_nan=False)
currents = st.lists(st.floats(-2.0, 2.0, allow_nan=False), min_size=3, max_size=3)
speeds = st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=3, max_size=3)


def _to_body(theta: float, vector: np.ndarray) -> np.ndarray:
    """R(theta)^T vector: odom-frame components of a planar vector into base_link (REP-103, yaw CCW)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([c * vector[0] + s * vector[1], -s * vector[0] + c * vector[1]])


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def test_wheels_sit_at_l_120_degrees_apart_rolling_counter_clockwise():
    p, d = model.wheel_positions(ROBOT), model.wheel_rolling_directions()
    np.testing.assert_allclose(np.hypot(p[:, 0], p[:, 1]), ROBOT.l, rtol=1e-15)
    np.testing.assert_allclose(np.hypot(d[:, 0], d[:, 1]), 1.0, rtol=1e-15)
    np.testing.assert_allclose(p.sum(axis=0), 0.0, atol=1e-16)  # 120 degrees apart
    # the rolling direction is the position turned by +90 degrees: the counter-clockwise tangent
    np.testing.assert_allclose(d, np.column_stack((-p[:, 1], p[:, 0])) / ROBOT.l, atol=1e-15)
    np.testing.assert_allclose(p[0], [ROBOT.l, 0.0], atol=1e-16)  # wheel 0 on base_link's +x axis


@settings(max_examples=200, deadline=None)
@given(theta=angles, other=angles, i=currents)
def test_body_frame_acceleration_does_not_depend_on_the_heading(theta, other, i):
    forces = model.wheel_forces(np.array(i), ROBOT)
    a, b = model.acceleration_block(theta, ROBOT) @ forces, model.acceleration_block(other, ROBOT) @ forces
    np.testing.assert_allclose(_to_body(theta, a[:2]), _to_body(other, b[:2]), rtol=0, atol=1e-12)
    assert a[2] == b[2]


@settings(max_examples=200, deadline=None)
@given(theta=angles, i=currents)
def test_g_theta_is_the_rigid_body_with_the_wheels_at_their_positions(theta, i):
    forces = model.wheel_forces(np.array(i), ROBOT)
    positions, rolling = model.wheel_positions(ROBOT), model.wheel_rolling_directions()
    force_body = sum(F * d for F, d in zip(forces, rolling))
    torque = sum(_cross(r, F * d) for r, F, d in zip(positions, forces, rolling))
    acc = (model.g_theta(theta, ROBOT) @ forces)[model.VELOCITY_INDEX]
    np.testing.assert_allclose(_to_body(theta, acc[:2]), force_body / ROBOT.M, rtol=0, atol=1e-12)
    assert math.isclose(acc[2], torque / ROBOT.J, rel_tol=1e-12, abs_tol=1e-12)


@settings(max_examples=200, deadline=None)
@given(theta=angles, v=speeds)
def test_rim_speeds_are_the_contact_velocities_along_the_rolling_directions(theta, v):
    """No slip: v_i = (v_body + omega x p_i) . d_i(0), the kinematics dual to g(theta)."""
    v_body, omega = _to_body(theta, np.array(v[:2])), v[2]
    expected = [
        float(np.dot(v_body + omega * np.array([-r[1], r[0]]), d))
        for r, d in zip(model.wheel_positions(ROBOT), model.wheel_rolling_directions())
    ]
    np.testing.assert_allclose(model.wheel_rim_speeds(theta, np.array(v), ROBOT), expected, rtol=0, atol=1e-12)


def _voltages(u_body: tuple[float, float, float]) -> np.ndarray:
    """A voltage pattern along the currents that give the body-frame acceleration u_body (T(0), eqs. 36-37)."""
    currents = model.currents_from_forces(DecouplingField(ROBOT).field(0.0) @ np.array(u_body), ROBOT)
    return 6.0 * currents / np.abs(currents).max()


def test_a_positive_rotation_command_turns_the_robot_counter_clockwise():
    plant = RobotinoPlant(ROBOT)
    U = _voltages((0.0, 0.0, 1.0))
    assert np.all(U > 0.0)
    yaws = []
    for _ in range(100):
        plant.step(U, TS)
        yaws.append(plant.pose[2])
    assert np.all(np.diff(yaws) > 0.0) and yaws[-1] > 0.5  # yaw increases: RViz shows a CCW turn
    assert np.hypot(*plant.pose[:2]) < 1e-12  # a pure rotation
    _, twist = plant.odometry()
    assert twist[2] > 0.0


def test_a_forward_command_at_yaw_pi_over_2_moves_along_odom_y():
    plant = RobotinoPlant(ROBOT, np.array([0.0, 0.0, 0.0, 0.0, 0.5 * math.pi, 0.0, 0.0, 0.0, 0.0]))
    for _ in range(100):
        plant.step(_voltages((1.0, 0.0, 0.0)), TS)
    x, y, theta = plant.pose
    assert y > 0.1 and abs(x) < 1e-9 * y
    assert abs(theta - 0.5 * math.pi) < 1e-12  # the summed current is zero: no turn
    _, twist = plant.odometry()  # the message's twist, in base_link (REP-105 child frame): forward
    assert twist[0] > 0.05 and abs(twist[1]) < 1e-9 * twist[0] and abs(twist[2]) < 1e-12


def test_encoder_dead_reckoning_follows_the_plant_while_it_turns_and_drives():
    """Odometry integrated from wheel counts through the body-frame kinematics agrees with the plant's pose."""
    plant = RobotinoPlant(ROBOT)
    odometry = EncoderOdometry(plant, counts_per_rev=2048)
    U = _voltages((1.0, 0.0, 0.0)) + 0.5 * _voltages((0.0, 0.0, 1.0))  # drive forward while turning CCW
    for _ in range(300):
        plant.step(U, TS)
        odometry.update()
    x, y, theta = plant.pose
    assert theta > math.pi and np.hypot(x, y) > 0.1  # turned more than half a circle along an arc
    assert np.hypot(odometry.pose[0] - x, odometry.pose[1] - y) < 1e-3 * np.hypot(x, y)
    assert abs(odometry.pose[2] - theta) < 1e-3
