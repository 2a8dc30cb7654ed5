"""Nav2's FollowPath semantics (reference.follow_path.PathFollower) in-process, on a hand-driven clock.

The robot here is where the reference is (a perfect tracker) unless a case holds it back; the closed loop over DDS
is test_follow_path. Truths: nav2_msgs' own error codes, the path's poses moved by the transform (computed here with
4x4 matrices), the reference's state before a switch (continuity), and the path's length summed here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from nav2_msgs.action import FollowPath
from test_goal_motion import limits, usage

from robotino_geom_mpc.reference.follow_path import FEEDBACK_PERIOD_S, FollowPathError, FollowPathSettings, Nav2Error, \
    PathFollower
from robotino_geom_mpc.reference.frames import TransformTree
from robotino_geom_mpc.reference.goals import GoalReference, ShiftedMotion
from robotino_geom_mpc.reference.path_timing import PathMotion

pytestmark = pytest.mark.unit

DT = 0.01
IDS = ("", "", "")


def _line(start, end, step: float = 0.05) -> np.ndarray:
    start, end = np.asarray(start, float), np.asarray(end, float)
    n = max(1, int(math.ceil(np.hypot(*(end - start)) / step)))
    xy = start + np.linspace(0.0, 1.0, n + 1)[:, None] * (end - start)
    return np.column_stack((xy, np.zeros(n + 1)))


def _follower(tree: TransformTree | None = None, **settings) -> PathFollower:
    tree = tree or TransformTree()
    return PathFollower(GoalReference(), "odom", tree.lookup, FollowPathSettings(**settings))


def _run(f: PathFollower, t: float, until_s: float, robot=None):
    """Step every DT from t until an outcome or `until_s`; the robot at the reference unless `robot` is given."""
    while t < until_s:
        t = round(t + DT, 9)
        pose = tuple(f.reference.state(t)[0]) if robot is None else robot
        outcome = f.step(t, pose, limits())
        if outcome is not None:
            return outcome, t
    return None, t


def test_error_codes_are_nav2s():
    for code in Nav2Error:
        assert getattr(FollowPath.Result, code.name) == code.value


def test_a_path_is_followed_to_its_end_and_succeeds():
    f = _follower()
    path = np.vstack((_line((0, 0), (1.0, 0)), _line((1.0, 0), (1.0, 0.8))[1:]))
    f.start(0.0, "odom", path, ("FollowPath", "goal_checker", "progress_checker"), limits())
    distance, speed = f.feedback(0.0, (0.0, 0.0, 0.0))
    assert distance == pytest.approx(1.8, abs=1e-9) and speed == 0.0
    outcome, t = _run(f, 0.0, 60.0)
    assert outcome.status == "succeeded" and outcome.code == Nav2Error.NONE
    assert t == pytest.approx(f.reference.motion_end_s, abs=DT)  # as soon as the reference rests at the end
    np.testing.assert_allclose(f.reference.state(t)[0], path[-1], atol=1e-12)
    assert not f.active


@pytest.mark.parametrize("ids", [("DWB", "", ""), ("", "precise", ""), ("", "", "stalled")])
def test_unknown_ids_are_invalid_controller(ids):
    with pytest.raises(FollowPathError) as info:
        _follower().start(0.0, "odom", _line((0, 0), (1, 0)), ids, limits())
    assert info.value.code == Nav2Error.INVALID_CONTROLLER


@pytest.mark.parametrize("frame, poses, code", [
    ("odom", np.zeros((0, 3)), Nav2Error.INVALID_PATH),
    ("odom", [[0.1, math.nan, 0.0]], Nav2Error.INVALID_PATH),
    ("", [[0.1, 0.0, 0.0]], Nav2Error.INVALID_PATH),
    ("map", [[0.1, 0.0, 0.0]], Nav2Error.TF_ERROR),
    ("odom", [[1e6, 0.0, 0.0]], Nav2Error.NO_VALID_CONTROL),  # beyond 600 s within the limits
], ids=["empty", "nan", "no_frame", "no_transform", "unreachable"])
def test_bad_goals_get_their_code_and_leave_the_reference(frame, poses, code):
    f = _follower()
    f.start(0.0, "odom", _line((0, 0), (1, 0)), IDS, limits())
    t = np.linspace(0.0, 10.0, 101)
    before = f.reference.sample(t)
    with pytest.raises(FollowPathError) as info:
        f.start(1.0, frame, np.asarray(poses, float), IDS, limits())
    assert info.value.code == code
    for x, y in zip(before, f.reference.sample(t)):
        np.testing.assert_array_equal(x, y)
    outcome = f.refuse(1.0, limits(), info.value)  # Nav2 ends the running goal too: the reference brakes
    assert outcome.code == code and not f.active
    rest = f.reference.state(f.reference.duration_s + 1.0)
    np.testing.assert_allclose(rest[1:], 0.0, atol=1e-12)
    np.testing.assert_allclose(f.reference.state(1.0), f.reference.state(1.0 - 1e-12), atol=1e-9)


def test_a_new_goal_takes_over_without_a_jump_and_from_where_the_reference_is():
    f = _follower()
    f.start(0.0, "odom", _line((0, 0), (2.0, 0)), IDS, limits())
    switch = 3.0
    before = f.reference.state(switch)
    assert before[1, 0] > 0.2
    # the replanned path starts at the robot, a little behind the reference (planning took time): pruned
    f.start(switch, "odom", _line((before[0, 0] - 0.04, 0.0), (1.5, 0.6)), IDS, limits())
    np.testing.assert_allclose(f.reference.state(switch), before, atol=1e-9)
    t = np.linspace(switch, f.reference.motion_end_s, 20001)
    p, v, a, j = f.reference.sample(t)
    assert usage(p[:, 2], v, a, j, limits()) <= 1.0 + 1e-6
    assert np.all(np.diff(p[:200, 0]) > 0.0)  # it does not go back to the path's first pose
    outcome, _ = _run(f, switch, 60.0)
    assert outcome.status == "succeeded"


def test_a_path_in_map_is_moved_into_odom_and_a_correction_followed():
    tree = TransformTree()
    psi = math.radians(30.0)
    tree.set("map", "odom", (0.5, 0.3, 0.0), (0.0, 0.0, math.sin(psi / 2), math.cos(psi / 2)), 0, static=False)
    f = _follower(tree)
    path = np.vstack((_line((0.6, 0.4), (1.6, 0.4)), _line((1.6, 0.4), (1.6, 1.2))[1:]))
    f.start(0.0, "map", path, IDS, limits())

    def in_odom(x: float, y: float, theta: float) -> np.ndarray:  # truth: p_odom = (T_map_odom)^-1 p_map
        m = np.eye(3)
        m[:2, :2] = [[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]]
        m[:2, 2] = (x, y)
        end = np.linalg.inv(m) @ [*path[-1, :2], 1.0]
        return np.array([end[0], end[1], path[-1, 2] - theta])

    outcome, t = _run(f, 0.0, 4.0)
    assert outcome is None
    tree.set("map", "odom", (0.52, 0.3, 0.0), (0.0, 0.0, math.sin(psi / 2), math.cos(psi / 2)), 1, static=False)
    before = f.reference.state(t + DT)
    outcome, t_end = _run(f, t, 60.0)
    assert outcome.status == "succeeded"
    np.testing.assert_allclose(f.reference.state(t_end)[0], in_odom(0.52, 0.3, psi), atol=1e-9)
    np.testing.assert_allclose(f.reference.state(t + DT), before, atol=1e-9)  # replanned from the state there


def test_a_robot_that_does_not_move_fails_to_make_progress_and_the_reference_brakes():
    f = _follower(required_movement_radius=0.3, movement_time_allowance=2.0)
    f.start(0.0, "odom", _line((0, 0), (2.0, 0)), IDS, limits())
    outcome, t = _run(f, 0.0, 10.0, robot=(0.0, 0.0, 0.0))
    assert outcome.code == Nav2Error.FAILED_TO_MAKE_PROGRESS and outcome.status == "aborted"
    assert t == pytest.approx(2.0 + DT, abs=1.5 * DT)
    np.testing.assert_allclose(f.reference.state(f.reference.duration_s + 1.0)[1:], 0.0, atol=1e-12)


def test_cancel_brakes_and_ends_when_the_reference_is_at_rest():
    f = _follower()
    f.start(0.0, "odom", _line((0, 0), (3.0, 0)), IDS, limits())
    _run(f, 0.0, 3.0)
    f.cancel(3.0, limits())
    outcome, t = _run(f, 3.0, 10.0)
    assert outcome.status == "canceled"
    assert t == pytest.approx(f.reference.motion_end_s, abs=DT)
    np.testing.assert_allclose(f.reference.state(t)[1:], 0.0, atol=1e-12)
    assert f.reference.state(t)[0, 0] < 3.0  # stopped short of the path's end


def test_feedback_is_the_remaining_path_length_from_the_robot():
    f = _follower()
    path = np.vstack((_line((0, 0), (1.0, 0)), _line((1.0, 0), (1.0, 1.0))[1:]))
    f.start(0.0, "odom", path, IDS, limits())
    distance, _ = f.feedback(1.0, (0.52, 0.01, 0.0))
    assert distance == pytest.approx(0.5 + 1.0, abs=1e-9)  # from the nearest pose (0.5, 0): 0.5 m, the corner, 1 m


@pytest.mark.parametrize("tolerance", [0.1, 0.0])
def test_a_replan_of_the_same_route_moves_the_end_without_retiming(tolerance):
    f = _follower(same_course_tolerance=tolerance)
    f.start(0.0, "odom", _line((0, 0), (2.5, 0.5)), IDS, limits())
    def end_of_motion() -> float:
        return f.reference.starts[-1] + f.reference.pieces[-1].duration_s

    switch, end = 3.0, end_of_motion()
    before = f.reference.state(switch)
    # bt_navigator's replan: from the robot to the goal moved by 4 cm
    f.start(switch, "odom", _line(before[0, :2], (2.5, 0.54)), IDS, limits())
    np.testing.assert_allclose(f.reference.state(switch), before, atol=1e-9)
    piece = f.reference.pieces[-1]
    if tolerance:  # not retimed: it ends when it would have, the end moved
        assert isinstance(piece, ShiftedMotion) and end_of_motion() == pytest.approx(end, abs=1e-9)
        speed = np.hypot(*f.reference.sample(np.linspace(switch, switch + 1.0, 101))[1][:, :2].T)
        assert speed.min() > 0.95 * np.hypot(*before[1, :2])  # at its cruise on
    else:  # retimed along the new path from the reference's state: later
        assert isinstance(piece, PathMotion) and end_of_motion() > end + 0.5
    outcome, t = _run(f, switch, 60.0)
    assert outcome.status == "succeeded"
    np.testing.assert_allclose(f.reference.state(t)[0], [2.5, 0.54, 0.0], atol=1e-9)


def test_feedback_keeps_its_20_hz_grid_when_the_periods_jitter():
    f = _follower()
    f.start(0.0, "odom", _line((0, 0), (1.0, 0)), IDS, limits())
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.008, 0.0125, 2000))  # a realtime timer's 10 ms, jittered
    fed = [t for t in times if f.due_feedback(float(t), None) is not None]
    assert len(fed) == pytest.approx(times[-1] / FEEDBACK_PERIOD_S, abs=2)  # none lost to the jitter
    assert np.diff(fed).max() < FEEDBACK_PERIOD_S + 0.0125


def test_a_short_path_succeeds_when_it_ends_not_when_the_goals_hold_does():
    f = PathFollower(GoalReference(hold_s=30.0), "odom", TransformTree().lookup, FollowPathSettings())
    f.start(0.0, "odom", _line((0, 0), (0.3, 0)), IDS, limits())
    end = f.reference.motion_end_s
    assert end < 5.0 < f.reference.duration_s
    outcome, t = _run(f, 0.0, 40.0)
    assert outcome.status == "succeeded" and t == pytest.approx(end, abs=DT)


@pytest.mark.parametrize("use_path_orientations", [False, True])
def test_headings_by_default_turn_to_the_last_poses_along_the_path(use_path_orientations):
    # NavFn's path: every pose at yaw 0 but the last, which has the goal's heading; the robot heads 1.2 rad
    f = PathFollower(GoalReference(start=(0.0, 0.0, 1.2)), "odom", TransformTree().lookup,
                     FollowPathSettings(use_path_orientations=use_path_orientations))
    path = _line((0, 0), (1.5, 0))
    path[-1, 2] = 1.6
    f.start(0.0, "odom", path, IDS, limits())
    t = np.linspace(0.0, f.reference.motion_end_s, 4001)
    p = f.reference.sample(t)[0]
    np.testing.assert_allclose(p[-1], [1.5, 0.0, 1.6], atol=1e-9)
    if use_path_orientations:  # through the poses' yaw 0 on the way
        assert np.abs(p[len(t) // 2, 2]) < 0.05
    else:  # 1.2 to 1.6 in proportion to the distance along: never near 0, heading and position in step
        assert p[:, 2].min() > 1.2 - 1e-6
        np.testing.assert_allclose(p[:, 2], 1.2 + 0.4 * p[:, 0] / 1.5, atol=0.02)
