"""reference.anchor: a scenario's reference moved rigidly onto the robot's pose.

The truths are independent of the module: the rigid move computed with complex numbers (z' = z0 + e^{i theta0} z),
the anchored velocities, accelerations and jerks against central differences of the anchored positions,
velocities and accelerations, and the circle's radius about its moved centre.
"""

import math

import numpy as np
import pytest

from robotino_geom_mpc.reference.anchor import AnchoredReference, anchored
from robotino_geom_mpc.reference.goal_file import LIMIT_DEFAULTS, motion_limits
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.ros.parameters import spec_defaults
from robotino_geom_mpc.reference.trajectories import TrajectoryError, make_reference, preview
from robotino_geom_mpc.ros.messages import preview_values

pytestmark = pytest.mark.unit

POSES = [(0.55, -0.3, 2.5), (-1.2, 0.4, -3.0), (0.0, 0.0, 0.0), (3.0, 2.0, 7.0)]  # the last: beyond a turn
SCENARIOS = ["paper-circle", "lemniscate", "point-to-point"]
H = 1e-4  # central difference step [s]


def _moved(positions: np.ndarray, pose) -> np.ndarray:
    """The rigid move of (x, y, theta) rows, by complex multiplication."""
    x0, y0, theta0 = pose
    z = (x0 + 1j * y0) + np.exp(1j * theta0) * (positions[:, 0] + 1j * positions[:, 1])
    return np.column_stack((z.real, z.imag, positions[:, 2] + theta0))


def _central(f, t: np.ndarray) -> np.ndarray:
    return (f(t + H) - f(t - H)) / (2 * H)


@pytest.mark.parametrize("pose", POSES)
@pytest.mark.parametrize("name", SCENARIOS)
def test_the_anchored_reference_is_the_scenario_moved_rigidly_and_its_derivatives_are_those_of_its_positions(
        name, pose):
    reference = make_reference(name)
    moved = anchored(reference, pose)
    assert isinstance(moved, AnchoredReference) and moved.duration_s == reference.duration_s
    t = np.linspace(0.0, reference.duration_s, 997)
    pos, vel, acc, jerk = moved.sample(t)
    np.testing.assert_allclose(pos, _moved(reference.position(t), pose), atol=1e-12)
    np.testing.assert_allclose(moved.position(t), pos, atol=0.0)
    # the derivatives against central differences (error ~ H^2 |next derivative| / 6: below 1e-7 here)
    inner = t[(t > 2 * H) & (t < reference.duration_s - 2 * H)]
    p, v, a, j = (np.asarray(x) for x in moved.sample(inner))
    np.testing.assert_allclose(v, _central(moved.position, inner), atol=1e-6)
    np.testing.assert_allclose(a, _central(lambda s: moved.sample(s)[1], inner), atol=1e-6)
    np.testing.assert_allclose(j, _central(lambda s: moved.sample(s)[2], inner), atol=1e-5)
    # the scalar kernel the preview uses agrees with the vector one
    np.testing.assert_allclose(preview(moved, 3.21, 0.01, 20), moved.position(3.21 + 0.01 * np.arange(1, 21)),
                               atol=1e-12)
    # it starts at the pose, at rest (every scenario starts at the origin at rest)
    start = [np.asarray(x) for x in moved.sample(0.0)]
    np.testing.assert_allclose(start[0], pose, atol=1e-12)
    for derivative in start[1:]:
        assert np.abs(derivative).max() < 1e-12


@pytest.mark.parametrize("pose", POSES)
def test_the_anchored_circle_runs_around_the_centre_to_the_robots_left_and_ends_where_it_started(pose):
    reference = make_reference("paper-circle")
    moved = anchored(reference, pose)
    x0, y0, theta0 = pose
    centre = np.array([x0 - reference.radius_m * math.sin(theta0), y0 + reference.radius_m * math.cos(theta0)])
    pos = moved.position(np.linspace(0.0, reference.duration_s, 500))
    np.testing.assert_allclose(np.hypot(*(pos[:, :2] - centre).T), reference.radius_m, atol=1e-12)
    np.testing.assert_allclose(pos[:, 2], theta0, atol=0.0)  # paper-circle keeps theta_d = 0: the start heading
    np.testing.assert_allclose(pos[-1], pose, atol=1e-12)


def test_the_preview_of_an_anchored_reference_is_its_samples():
    moved = anchored(make_reference("lemniscate"), (0.2, -0.1, 1.0))
    values = np.reshape(preview_values(moved, 4_500_000_000, 0.02, 10), (11, 10))
    pos, vel, acc, _ = moved.sample(4.5 + 0.02 * np.arange(11))
    np.testing.assert_allclose(values[:, :2], pos[:, :2], atol=1e-12)
    np.testing.assert_allclose(2 * np.arctan2(values[:, 2], values[:, 3]), np.angle(np.exp(1j * pos[:, 2])),
                               atol=1e-12)
    np.testing.assert_allclose(values[:, 4:7], vel, atol=1e-12)
    np.testing.assert_allclose(values[:, 7:10], acc, atol=1e-12)


def test_goals_anchored_hold_the_pose_and_goals_stay_absolute():
    held = anchored(GoalReference(hold_s=7.0), (0.4, 0.3, -1.0))
    assert isinstance(held, GoalReference) and held.hold_s == 7.0
    np.testing.assert_allclose(held.state(5.0), [[0.4, 0.3, -1.0], [0, 0, 0], [0, 0, 0], [0, 0, 0]], atol=0.0)
    goal = np.array([1.0, -0.5, 0.5])
    held.go_to(1.0, goal, motion_limits({**spec_defaults(), **LIMIT_DEFAULTS}))
    np.testing.assert_allclose(held.state(held.duration_s + 1.0)[0], goal, atol=1e-9)  # where it was sent, in odom
    with pytest.raises(TrajectoryError, match="before its first goal"):
        anchored(held, (0.0, 0.0, 0.0))


@pytest.mark.parametrize("pose, match", [((0.0, math.nan, 0.0), "finite"), ((1.0, 2.0), "shape"),
                                         ("here", "anchor pose")])
def test_a_bad_pose_is_refused(pose, match):
    with pytest.raises(TrajectoryError, match=match):
        anchored(make_reference("paper-circle"), pose)
    with pytest.raises(TrajectoryError, match=match):
        anchored(GoalReference(), pose)
