"""reference.frames: rigid transforms and the tree's lookups, without tf2.

The truth is independent of the module: 4x4 homogeneous matrices built with scipy's `Rotation` from the same
translations and quaternions, multiplied along the chain from each frame up to the root; a lookup (target,
source) is then M_root_target^-1 M_root_source, and a planar pose is the matrix of its own frame (rotation about
z by its yaw at (x, y, 0)) multiplied by the transform's.
"""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.reference.frames import FrameError, Rigid, TransformTree, transform_planar

pytestmark = pytest.mark.unit

TOL = 1e-9
SECOND = 1_000_000_000

coordinates = st.floats(-10.0, 10.0, allow_nan=False)
translations = st.tuples(coordinates, coordinates, coordinates)


@st.composite
def quaternions(draw) -> tuple[float, float, float, float]:
    """A unit quaternion (x, y, z, w): four numbers normalized (those near zero left out)."""
    q = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0)] * 4)))
    assume(np.linalg.norm(q) > 0.1)
    return tuple((q / np.linalg.norm(q)).tolist())


rigids = st.builds(Rigid, translations, quaternions())


def matrix(translation, rotation_xyzw) -> np.ndarray:
    """The 4x4 homogeneous matrix of a transform, with scipy's rotation of the quaternion."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(rotation_xyzw).as_matrix()
    m[:3, 3] = translation
    return m


def matrix_of(rigid: Rigid) -> np.ndarray:
    return matrix(rigid.translation, rigid.rotation)


def planar_matrix(x: float, y: float, yaw: float, z: float = 0.0) -> np.ndarray:
    return matrix((x, y, z), Rotation.from_euler("z", yaw).as_quat())


def wrapped(angle):
    return np.angle(np.exp(1j * np.asarray(angle)))


@st.composite
def trees(draw) -> tuple[list[tuple[int, int, tuple, tuple]], int]:
    """Edges (parent, child, translation, quaternion) of a random tree of frames 0..n-1 rooted at 0, in a random
    order of setting, and n.
    """
    n = draw(st.integers(2, 7))
    edges = [(draw(st.integers(0, child - 1)), child, draw(translations), draw(quaternions()))
             for child in range(1, n)]
    return draw(st.permutations(edges)), n


@settings(max_examples=150, deadline=None)
@given(tree=trees(), points=st.lists(translations, min_size=1, max_size=4))
def test_a_lookup_through_a_tree_is_the_product_of_the_matrices_along_the_chain(tree, points):
    edges, n = tree
    frames = [f"f{i}" for i in range(n)]
    t = TransformTree()
    for parent, child, translation, q in edges:
        t.set(frames[parent], frames[child], translation, q, stamp_ns=0)
    parent_of = {child: (parent, matrix(translation, q)) for parent, child, translation, q in edges}
    in_root = [np.eye(4)]  # M_root_i, the parents come first
    for i in range(1, n):
        parent, m = parent_of[i]
        in_root.append(in_root[parent] @ m)
    p = np.array(points)
    for target in range(n):
        for source in range(n):
            truth = np.linalg.inv(in_root[target]) @ in_root[source]
            got = t.lookup(frames[target], frames[source])
            np.testing.assert_allclose(matrix_of(got), truth, atol=TOL)
            np.testing.assert_allclose(got.apply(p), p @ truth[:3, :3].T + truth[:3, 3], atol=TOL)


@settings(max_examples=200, deadline=None)
@given(a=rigids, b=rigids, point=translations)
def test_composition_and_inverse_are_those_of_the_matrices_and_round_trip(a, b, point):
    np.testing.assert_allclose(matrix_of(a @ b), matrix_of(a) @ matrix_of(b), atol=TOL)
    np.testing.assert_allclose(matrix_of(a.inverse()), np.linalg.inv(matrix_of(a)), atol=TOL)
    np.testing.assert_allclose((a @ a.inverse()).apply(point), point, atol=TOL)
    np.testing.assert_allclose((a.inverse() @ a).apply(point), point, atol=TOL)
    np.testing.assert_allclose(a.inverse().apply(a.apply(point)), point, atol=TOL)
    np.testing.assert_allclose((a @ b).apply(point), a.apply(b.apply(point)), atol=TOL)
    assert np.linalg.norm((a @ b).rotation) == pytest.approx(1.0, abs=1e-15)


@settings(max_examples=200, deadline=None)
@given(x=coordinates, y=coordinates, z=coordinates, psi=st.floats(-3 * math.pi, 3 * math.pi),
       poses=st.lists(st.tuples(coordinates, coordinates, st.floats(-10.0, 10.0)), min_size=1, max_size=5))
def test_planar_poses_move_as_the_matrices_and_keep_their_yaw_unwrapped(x, y, z, psi, poses):
    m = planar_matrix(x, y, psi, z)  # a vertical offset z leaves the planar pose as it is
    transform = Rigid((x, y, z), Rotation.from_euler("z", psi).as_quat())
    tx, ty, yaw = transform.planar()
    assert (tx, ty) == pytest.approx((x, y), abs=TOL)
    assert -math.pi < yaw <= math.pi and wrapped(yaw - psi) == pytest.approx(0.0, abs=TOL)
    p = np.array(poses)
    got = transform_planar(transform, p)
    assert got.shape == p.shape
    for row, pose in zip(got, p):
        truth = m @ planar_matrix(*pose)
        np.testing.assert_allclose(row[:2], truth[:2, 3], atol=TOL)
        truth_yaw = Rotation.from_matrix(truth[:3, :3]).as_euler("ZYX")[0]
        assert wrapped(row[2] - truth_yaw) == pytest.approx(0.0, abs=TOL)
    np.testing.assert_allclose(got[:, 2] - p[:, 2], yaw, atol=TOL)  # not wrapped: the same yaw added to each
    np.testing.assert_allclose(transform_planar(transform, p[0]), got[0], atol=TOL)


def test_equal_frames_give_the_identity_even_unknown_ones():
    t = TransformTree()
    t.set("map", "odom", (1.0, 2.0, 3.0), Rotation.from_euler("z", 0.4).as_quat(), 0)
    for frame in ("odom", "nowhere", "/nowhere"):
        np.testing.assert_array_equal(matrix_of(t.lookup(frame, frame)), np.eye(4))


def _refused(reason: str, call, *args, **kwargs) -> FrameError:
    with pytest.raises(FrameError) as info:
        call(*args, **kwargs)
    assert info.value.reason == reason, str(info.value)
    assert isinstance(info.value, RobotinoError) and isinstance(info.value, ValueError)
    return info.value


Q0 = (0.0, 0.0, 0.0, 1.0)


def test_unknown_frames_and_two_trees_have_no_transform():
    t = TransformTree()
    t.set("map", "odom", (1.0, 0.0, 0.0), Q0, 0)
    t.set("base_link", "laser", (0.1, 0.0, 0.2), Q0, 0)
    assert "nowhere" in str(_refused("unknown_frame", t.lookup, "map", "nowhere"))
    _refused("unknown_frame", t.lookup, "nowhere", "map")
    _refused("no_path", t.lookup, "map", "laser")
    _refused("no_path", t.lookup, "odom", "base_link")


def test_a_dynamic_edge_older_than_max_age_is_stale_and_a_static_one_never():
    t = TransformTree()
    t.set("map", "odom", (1.0, 0.0, 0.0), Q0, 10 * SECOND)
    t.set("odom", "base_link", (2.0, 0.0, 0.0), Q0, 0, static=True)
    fresh = t.lookup("map", "base_link", now_ns=11 * SECOND, max_age_s=1.5)
    np.testing.assert_allclose(fresh.translation, (3.0, 0.0, 0.0))
    error = _refused("stale", t.lookup, "map", "base_link", now_ns=12 * SECOND, max_age_s=1.5)
    assert "'map' -> 'odom'" in str(error)
    _refused("stale", t.lookup, "base_link", "map", now_ns=12 * SECOND, max_age_s=1.5)  # either direction
    # the static edge alone, however old, and a stamp ahead of now
    t.lookup("odom", "base_link", now_ns=10**6 * SECOND, max_age_s=0.0)
    t.lookup("map", "odom", now_ns=5 * SECOND, max_age_s=0.0)
    _refused("usage", t.lookup, "map", "odom", now_ns=11 * SECOND)
    _refused("usage", t.lookup, "map", "odom", max_age_s=1.0)
    _refused("usage", t.lookup, "map", "odom", now_ns=11 * SECOND, max_age_s=float("nan"))


@pytest.mark.parametrize(("translation", "rotation", "reason"), [
    ((float("nan"), 0.0, 0.0), Q0, "non_finite"),
    ((0.0, 0.0, 0.0), (0.0, 0.0, float("inf"), 1.0), "non_finite"),
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), "not_unit"),
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.5, 0.5), "not_unit"),  # norm 0.707: not pi/2 about z
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.002), "not_unit"),
    ((0.0, 0.0), Q0, "shape"),
])
def test_a_refused_transform_leaves_the_tree_unchanged(translation, rotation, reason):
    t = TransformTree()
    t.set("map", "odom", (1.0, 2.0, 0.0), Q0, 0)
    _refused(reason, t.set, "map", "odom", translation, rotation, 1)
    np.testing.assert_allclose(t.lookup("map", "odom").translation, (1.0, 2.0, 0.0))


def test_a_nearly_unit_quaternion_is_normalized():
    q = np.array([0.0, 0.0, math.sin(0.3), math.cos(0.3)]) * 1.0009
    t = TransformTree()
    t.set("map", "odom", (0.0, 0.0, 0.0), q, 0)
    got = t.lookup("map", "odom").rotation
    assert np.linalg.norm(got) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(Rotation.from_quat(got).as_euler("ZYX")[0], 0.6, atol=1e-12)


def test_a_loop_and_bad_frame_ids_are_refused():
    t = TransformTree()
    t.set("a", "b", (1.0, 0.0, 0.0), Q0, 0)
    t.set("b", "c", (2.0, 0.0, 0.0), Q0, 0)
    _refused("loop", t.set, "c", "a", (0.0, 0.0, 0.0), Q0, 0)
    _refused("loop", t.set, "c", "b", (0.0, 0.0, 0.0), Q0, 0)
    np.testing.assert_allclose(t.lookup("a", "c").translation, (3.0, 0.0, 0.0))  # unchanged
    _refused("same_frame", t.set, "a", "/a", (0.0, 0.0, 0.0), Q0, 0)
    _refused("empty_frame", t.set, "", "a", (0.0, 0.0, 0.0), Q0, 0)
    _refused("empty_frame", t.set, "a", "/", (0.0, 0.0, 0.0), Q0, 0)
    _refused("empty_frame", t.lookup, "", "a")


def test_a_new_parent_replaces_the_childs_old_edge_as_in_tf2():
    t = TransformTree()
    t.set("map", "odom", (1.0, 0.0, 0.0), Q0, 0)
    t.set("earth", "odom", (0.0, 5.0, 0.0), Q0, 1)
    np.testing.assert_allclose(t.lookup("earth", "odom").translation, (0.0, 5.0, 0.0))
    _refused("no_path", t.lookup, "map", "odom")  # map stays known, alone
    t.set("map", "odom", (0.0, 0.0, 7.0), Q0, 2)  # the newest edge of each frame is the one looked up
    np.testing.assert_allclose(t.lookup("map", "odom").translation, (0.0, 0.0, 7.0))
    _refused("no_path", t.lookup, "earth", "odom")


def test_a_leading_slash_is_stripped():
    t = TransformTree()
    t.set("/map", "/odom", (1.0, 0.0, 0.0), Q0, 0)
    for target, source in (("map", "odom"), ("/map", "odom"), ("map", "/odom")):
        np.testing.assert_allclose(t.lookup(target, source).translation, (1.0, 0.0, 0.0))


def test_a_rotation_that_tilts_z_is_not_planar():
    tilted = Rigid((1.0, 2.0, 0.0), Rotation.from_euler("xz", (1e-4, 0.5)).as_quat())
    _refused("not_planar", tilted.planar)
    _refused("not_planar", transform_planar, tilted, (0.0, 0.0, 0.0))
    barely = Rigid((1.0, 2.0, 0.0), Rotation.from_euler("xz", (1e-7, 0.5)).as_quat())
    assert barely.planar()[2] == pytest.approx(0.5, abs=1e-9)
    flat = Rigid((0.0, 0.0, 0.0), Q0)
    _refused("shape", transform_planar, flat, np.zeros((2, 2)))
    _refused("non_finite", transform_planar, flat, (0.0, float("nan"), 0.0))
