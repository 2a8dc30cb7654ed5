"""The controller loop's input conversions on Python floats (`loop.inputs`) against independent numpy forms."""

import math

import numpy as np
import pytest

from robotino_geom_mpc.loop.inputs import POINT_SIZE, InputRejected, preview_of_values, unwrap_near

pytestmark = pytest.mark.unit


def test_unwrap_near_is_the_nearest_turn_bit_for_bit():
    """The shortcut for k = 0 gives the float of angle + 2 pi round((reference - angle) / 2 pi), signed zeros and
    the half-turn boundaries included.
    """
    rng = np.random.default_rng(5)
    angles = [-0.0, 0.0, math.pi, -math.pi, 1e-300, *rng.uniform(-math.pi, math.pi, 300)]
    references = [-0.0, 0.0, math.pi, -math.pi, 2 * math.pi, math.nextafter(math.pi, 0.0),
                  *rng.uniform(-20.0, 20.0, 400)]
    for angle in angles:
        for reference in references:
            expected = angle + 2.0 * math.pi * round((reference - angle) / (2.0 * math.pi))
            got = unwrap_near(angle, reference)
            assert got == expected and math.copysign(1.0, got) == math.copysign(1.0, expected), (angle, reference)
    assert abs(unwrap_near(-3.1, 3.1) - (2 * math.pi - 3.1)) < 1e-15  # across the cut: one turn added


def _points(thetas, rng):
    rows = []
    for theta in thetas:
        x, y = rng.uniform(-2.0, 2.0, 2)
        rows += [x, y, 0.0, 0.0, math.sin(0.5 * theta), math.cos(0.5 * theta), *rng.normal(size=6)]
    return tuple(rows)


def test_preview_of_values_unwraps_every_point_from_the_last():
    """Positions, velocities and accelerations of a preview whose heading turns through the +-pi cut: theta the
    continuous heading (numpy's arctan2 and unwrap from the given start), the rest as sent.
    """
    rng = np.random.default_rng(9)
    thetas = np.linspace(2.9, 3.5, 6) + 2 * math.pi  # a second turn, crossing pi
    values = _points(thetas, rng)
    positions, velocities, accelerations = preview_of_values(values, 2 * math.pi + 2.8)
    points = np.array(values).reshape(-1, POINT_SIZE)
    yaw = np.arctan2(2.0 * points[:, 5] * points[:, 4], 1.0 - 2.0 * points[:, 4] ** 2)
    np.testing.assert_allclose(positions[:, 2], np.unwrap(np.r_[2 * math.pi + 2.8, yaw])[1:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(positions[:, 2], thetas, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(positions[:, :2], points[:, :2])
    np.testing.assert_array_equal(velocities, points[:, 6:9])
    np.testing.assert_array_equal(accelerations, points[:, 9:12])


@pytest.mark.parametrize("point, quaternion, reason", [
    (0, (0.0, 0.0, 0.0, 0.0), "quaternion_norm"), (3, (0.0, 0.0, 0.5, 0.5), "quaternion_norm"),
    (4, (0.2, 0.0, 0.0, math.sqrt(0.96)), "quaternion_tilt")])
def test_preview_of_values_names_the_refused_point(point, quaternion, reason):
    values = list(_points(np.zeros(5), np.random.default_rng(1)))
    values[point * POINT_SIZE + 2:point * POINT_SIZE + 6] = quaternion
    with pytest.raises(InputRejected, match=f"point {point}") as refused:
        preview_of_values(tuple(values), 0.0)
    assert refused.value.reason == reason
    values[5] = math.inf
    with pytest.raises(InputRejected) as refused:
        preview_of_values(tuple(values), 0.0)
    assert refused.value.reason == "non_finite"
