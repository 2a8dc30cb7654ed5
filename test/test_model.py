"""The Robotino model (eqs. 1-10) against the notes' formulas, energy balances and eq. (10)."""

import numpy as np
import pytest

from robotino_geom_mpc.model import dynamics as model
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import preset_file

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module", params=("robotino3", "robotino2"))
def robot(request):
    return load_params(preset_file(request.param))[0]


THETAS = np.linspace(-np.pi, np.pi, 37)


def test_g_rows_are_the_printed_translation_rows_at_minus_theta_and_the_corrected_angular_row(robot):
    M, J, l, a = robot.M, robot.J, robot.l, 2 * np.pi / 3
    for th in THETAS:
        g = model.g_theta(th, robot)
        # rows 2 and 4 of eq. (9) as printed, (sin th, sin(a + th), -sin(a - th)) and (cos th, cos(a + th),
        # cos(a - th)), with the heading's sign corrected (erratum 6: the directions turn with the yaw)
        assert np.allclose(g[1], [-np.sin(th) / M, np.sin(a - th) / M, -np.sin(a + th) / M], atol=1e-15)
        assert np.allclose(g[3], [np.cos(th) / M, np.cos(a - th) / M, np.cos(a + th) / M], atol=1e-15)
        # erratum 1: every wheel gives torque l F_i
        assert np.allclose(g[5], l / J, atol=0.0)
        assert np.all(g[[0, 2, 4]] == 0.0)


def test_acceleration_block_has_the_constant_determinant(robot):
    # det [[s_i / M], [c_i / M], [l / J]] = (l / (J M^2)) (sin(-2pi/3) + sin(4pi/3) + sin(-2pi/3))
    expected = -1.5 * np.sqrt(3.0) * robot.l / (robot.J * robot.M**2)
    dets = [np.linalg.det(model.acceleration_block(th, robot)) for th in np.append(THETAS, [np.pi / 2, -np.pi / 2])]
    assert np.allclose(dets, expected, rtol=1e-12)


def test_A_and_C_are_eqs_3_and_5(robot):
    A = model.A_matrix(robot)
    expected = np.zeros((6, 6))
    expected[0, 1] = expected[2, 3] = expected[4, 5] = 1.0
    expected[1, 1], expected[3, 3] = -robot.k_x / robot.M, -robot.k_y / robot.M
    expected[5, 5] = -robot.k_theta / robot.J
    assert np.array_equal(A, expected)
    assert np.array_equal(model.C_matrix(), np.eye(6)[[0, 2, 4]])
    assert np.array_equal(np.vstack((model.C_x(), model.C_y(), model.C_theta())), model.C_matrix())


def _random_state(rng):
    s = rng.standard_normal(9)
    s[4] = rng.uniform(-np.pi, np.pi)
    return s, rng.uniform(-24.0, 24.0, 3)


def test_mechanical_power_balance(robot):
    """sum F_i v_i = d/dt kinetic energy + friction losses."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        s, U = _random_state(rng)
        d = model.coupled_rhs(s, U, robot)
        vel, acc = s[[1, 3, 5]], d[[1, 3, 5]]
        dE = robot.M * (vel[0] * acc[0] + vel[1] * acc[1]) + robot.J * vel[2] * acc[2]
        losses = robot.k_x * vel[0] ** 2 + robot.k_y * vel[1] ** 2 + robot.k_theta * vel[2] ** 2
        F = model.wheel_forces(s[6:], robot)
        v = model.wheel_rim_speeds(s[4], vel, robot)
        assert F @ v == pytest.approx(dE + losses, rel=1e-12, abs=1e-12)
        assert np.allclose(d[[0, 2, 4]], vel)


def test_back_emf_power_equals_wheel_power_and_electrical_balance(robot):
    rng = np.random.default_rng(1)
    Km, R, L = robot.torque_constant_n_m_per_a, robot.resistance_ohm, robot.inductance_h
    for _ in range(20):
        s, U = _random_state(rng)
        i = s[6:]
        omega = model.motor_speeds(s[4], s[[1, 3, 5]], robot)
        v = model.wheel_rim_speeds(s[4], s[[1, 3, 5]], robot)
        F = model.wheel_forces(i, robot)
        assert np.allclose(Km * omega * i, F * v, rtol=1e-12, atol=1e-12)
        di = model.coupled_rhs(s, U, robot)[6:]
        # U i = R i^2 + L i di/dt + Km omega i, wheel by wheel
        assert np.allclose(U * i, R * i**2 + L * i * di + Km * omega * i, rtol=1e-10, atol=1e-10)


def test_rim_speed_kinematics_is_dual_to_g(robot):
    """v = G^T-like map: the rim speeds are the transpose of g's direction rows (F . v = force . velocity)."""
    th, vel = 0.8, np.array([0.3, -0.2, 0.5])
    G3 = model.acceleration_block(th, robot)
    W = np.column_stack((G3[0] * robot.M, G3[1] * robot.M, G3[2] * robot.J))  # (d_x, d_y, l) per wheel
    assert np.allclose(model.wheel_rim_speeds(th, vel, robot), W @ vel)


def test_forces_and_currents_are_inverse_and_include_the_gear(robot):
    i = np.array([0.5, -0.2, 0.86])
    F = model.wheel_forces(i, robot)
    assert np.allclose(F, robot.gear_ratio * robot.torque_constant_n_m_per_a * i / robot.r)
    assert np.allclose(model.currents_from_forces(F, robot), i)


def test_drive_matrices_are_eq_10(robot):
    A, B = model.drive_matrices(robot)
    R, L, Km = robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a
    Jm, K = robot.rotor_inertia_kg_m2, robot.viscous_friction_n_m_s
    expected = np.zeros((6, 6))
    for k in range(3):
        expected[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[-R / L, -Km / L], [Km / Jm, -K / Jm]]
    assert np.allclose(A, expected, rtol=1e-15)
    assert np.array_equal(B, np.array([[1 / L, 0, 0], [0, 0, 0], [0, 1 / L, 0], [0, 0, 0], [0, 0, 1 / L], [0, 0, 0]]))


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda p: model.coupled_rhs(np.zeros(8), np.zeros(3), p), "state"),
        (lambda p: model.coupled_rhs(np.zeros(9), np.zeros(2), p), "voltages"),
        (lambda p: model.wheel_forces(np.zeros(4), p), "currents"),
        (lambda p: model.wheel_rim_speeds(0.0, np.zeros(2), p), "velocity"),
    ],
)
def test_bad_shapes_raise_model_error(robot, call, name):
    with pytest.raises(model.ModelError, match=name):
        call(robot)
