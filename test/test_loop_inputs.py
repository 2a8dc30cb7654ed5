"""The controller loop's input conversions on Python floats (`loop.inputs`) against independent numpy forms, and its
in-process (planar) inputs against the messages.
"""

import math

import numpy as np
import pytest

from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
from robotino_geom_mpc.loop.events import Command, Now, PlanarOdometry, PlanarPreview, Zero
from robotino_geom_mpc.loop.inputs import PLANAR_POINT_SIZE, POINT_SIZE, InputRejected, preview_of_values, unwrap_near
from robotino_geom_mpc.offline.lockstep import PreviewRows, odometry_event
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.scenarios import get_scenario

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


def _lockstep_run(planar: bool, ticks: int, heading_noise: float) -> list:
    """The answers of a lockstep loop over `ticks` ticks of paper-circle, its inputs as messages (quaternions) or in
    process (planar), the robot standing still at the start with a heading of `heading_noise` per tick.
    """
    robot, control = load_params(None)
    reference = get_scenario("paper-circle").make_reference()
    loop = ControllerLoop(robot, control, Now(0, 0), lockstep=True, listeners=QUIET)
    period_ns = round(control.period_s * 1e9)
    previews = PreviewRows(reference, control.period_s, period_ns, loop.preview_points, ticks)
    x0, y0, _ = previews.positions[0].tolist()
    out = []
    for k in range(ticks):
        now = Now(k * period_ns, k * period_ns)
        pose, twist = (x0, y0, heading_noise * k), (0.0, 0.0, 0.0)
        loop.on_preview(previews.planar(k) if planar else previews.at(k), now)
        odometry = PlanarOdometry(k * period_ns, pose, twist) if planar else odometry_event(k * period_ns, pose, twist)
        out += [o for o in loop.on_odometry(odometry, now) if isinstance(o, (Command, Zero))]
    return out


@pytest.mark.parametrize("heading_noise", [0.0, 1e-3])
def test_planar_inputs_are_answered_as_the_messages_are(heading_noise):
    """In process (`PlanarPreview`, `PlanarOdometry`) the loop answers as to the messages carrying the yaw as a
    quaternion: the same commands, to the last bit with a zero heading, else to the quaternion's rounding.
    """
    planar, messages = _lockstep_run(True, 30, heading_noise), _lockstep_run(False, 30, heading_noise)
    assert len(planar) == len(messages) == 30 and all(isinstance(o, Command) for o in planar + messages)
    values = np.array([o.values for o in planar])
    assert np.abs(values).max() > 0.1  # it drives
    np.testing.assert_allclose(values, [o.values for o in messages], rtol=0, atol=0 if heading_noise == 0 else 1e-9)


def test_a_bad_planar_input_is_refused_with_its_reason():
    robot, control = load_params(None)
    loop = ControllerLoop(robot, control, Now(0, 0), lockstep=True)
    previews = PreviewRows(get_scenario("paper-circle").make_reference(), control.period_s, 10_000_000,
                           loop.preview_points, 3)
    now = Now(0, 0)
    out = loop.on_odometry(PlanarOdometry(0, (0.5, 0.0, math.nan), (0.0, 0.0, 0.0)), now)
    assert any(isinstance(o, Zero) and o.reason == "non_finite" for o in out)
    short = previews.planar(1)
    out = loop.on_preview(PlanarPreview(short.stamp_ns, "odom", short.values[:-PLANAR_POINT_SIZE]), now)
    assert loop.counters.last_refusal == "size"
    bad = previews.planar(2)
    loop.on_preview(PlanarPreview(bad.stamp_ns, "odom", (math.inf, *bad.values[1:])), now)
    out = loop.on_odometry(PlanarOdometry(bad.stamp_ns, (0.5, 0.0, 0.0), (0.0, 0.0, 0.0)), now)
    assert any(isinstance(o, Zero) and o.reason == "preview_non_finite" for o in out)
    assert loop.counters.rejected == 4  # the odometry, the short preview, the bad one and its tick
