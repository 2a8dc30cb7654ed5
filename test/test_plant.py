"""The plant integrator against a tight reference solution of model.coupled_rhs; steady states; energy."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from robotino_geom_mpc.model.dynamics import coupled_rhs, wheel_rim_speeds
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.model.plant import PlantError, RobotinoPlant

pytestmark = pytest.mark.unit

DT = 0.01
ROBOT, _ = load_params()


def reference_run(p, state0, voltages, dt=DT, substeps=4):
    """DOP853 (rtol 1e-11, atol 1e-13) on coupled_rhs plus the wheel angles, restarted at each held voltage.

    Returns the states (len(voltages) + 1, 12) at the step ends and the
    (x, i) samples at the substep ends (for the peak currents).
    """

    def rhs(_t, s, U):
        return np.concatenate((coupled_rhs(s[:9], U, p), wheel_rim_speeds(s[4], s[[1, 3, 5]], p) / p.r))

    s = np.concatenate((state0, np.zeros(3)))
    out, fine = [s], []
    for U in voltages:
        sol = solve_ivp(
            rhs, (0.0, dt), s, method="DOP853", rtol=1e-11, atol=1e-13, args=(U,),
            t_eval=np.linspace(0.0, dt, substeps + 1),
        )
        assert sol.success
        s = sol.y[:, -1]
        out.append(s)
        fine.append(sol.y.T)
    return np.array(out), np.array(fine)


def plant_run(plant, voltages, dt=DT):
    out, peaks = [np.concatenate((plant.state, plant.wheel_angles))], []
    for U in voltages:
        plant.step(U, dt)
        out.append(np.concatenate((plant.state, plant.wheel_angles)))
        peaks.append(plant.peak_abs_currents)
    return np.array(out), np.array(peaks)


def rich_voltages(n, seed, bias=7.0, spread=12.0):
    """Random piecewise-constant voltages; the common bias makes the robot spin at a few rad/s."""
    return bias + np.random.default_rng(seed).uniform(-spread, spread, (n, 3))


def assert_close_run(got, ref, pos, angle, vel, current, wheel):
    err = np.abs(got - ref)
    assert err[:, [0, 2]].max() < pos
    assert err[:, 4].max() < angle
    assert err[:, [1, 3, 5]].max() < vel
    assert err[:, 6:9].max() < current
    assert err[:, 9:12].max() < wheel


STATE0 = np.array([0.3, 0.2, -0.1, -0.3, 2.0, 1.5, 0.4, -0.2, 0.1])


@pytest.mark.slow
def test_matches_tight_reference_with_rotation():
    # Measured (4 substeps): 1.3e-8 m, 2e-15 rad, 6e-9 m/s, 3.1e-7 A, 2e-8 rad of wheel; bounds with margin.
    U = rich_voltages(40, seed=1)
    ref, fine = reference_run(ROBOT, STATE0, U)
    plant = RobotinoPlant(ROBOT, STATE0)
    assert plant.isotropic
    got, peaks = plant_run(plant, U)
    assert np.abs(ref[:, 5]).max() > 2.5  # it really spins
    assert np.abs(ref[:, 6:9]).max() > 1.5  # and draws large currents
    assert_close_run(got, ref, pos=5e-8, angle=1e-10, vel=5e-8, current=2e-6, wheel=5e-7)
    np.testing.assert_allclose(peaks, np.abs(fine[:, :, 6:9]).max(axis=1), atol=2e-6)
    assert plant.time_s == pytest.approx(40 * DT)


def test_turn_rate_beyond_the_fit_uses_the_exact_path():
    # 30 rad/s exceeds the polynomial fit's 20 rad/s: the substep maps come from expm.
    state0 = np.array([0.0, 0.5, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0, 0.0])
    U = rich_voltages(8, seed=2, bias=20.0, spread=3.0)
    ref, _ = reference_run(ROBOT, state0, U)
    got, _ = plant_run(RobotinoPlant(ROBOT, state0), U)
    assert np.abs(ref[:, 5]).min() > 20.0
    assert_close_run(got, ref, pos=1e-8, angle=1e-9, vel=3e-8, current=2e-5, wheel=2e-7)


@pytest.mark.slow
def test_anisotropic_friction_fallback_matches_reference():
    robot = replace(ROBOT, body_friction_y_n_s_per_m=3.0 * ROBOT.k_x)
    U = rich_voltages(15, seed=3)
    ref, _ = reference_run(robot, STATE0, U)
    plant = RobotinoPlant(robot, STATE0)
    assert not plant.isotropic
    got, _ = plant_run(plant, U)
    assert_close_run(got, ref, pos=1e-7, angle=1e-10, vel=3e-7, current=2e-6, wheel=2e-6)


@pytest.mark.slow
def test_convergence_with_substeps():
    # Errors fall as the substeps grow (third order per substep in the heading's curvature).
    U = rich_voltages(20, seed=4)
    ref, _ = reference_run(ROBOT, STATE0, U)
    errors = []
    for n in (1, 2, 4):
        got, _ = plant_run(RobotinoPlant(ROBOT, STATE0, substeps=n), U)
        errors.append(np.abs(got - ref)[:, 6:9].max())
    assert errors[0] > 3.0 * errors[1] > 9.0 * errors[2]


def steady_state(p, U, theta):
    """Solve i' = 0, X'' = 0 for (v_x, v_y, theta', i_1, i_2, i_3) with the heading fixed."""
    k_wheel = p.gear_ratio * p.torque_constant_n_m_per_a / p.r
    phi = np.array([0.0, 2.0 * np.pi / 3.0, -2.0 * np.pi / 3.0])
    c, s = np.cos(theta), np.sin(theta)
    # drive directions, (3, 2): the body-frame ones (sin phi_i, cos phi_i) turned with the robot, R(theta) d_i(0)
    d = np.column_stack((np.sin(phi), np.cos(phi))) @ np.array([[c, s], [-s, c]])
    A = np.zeros((6, 6))
    A[0, 0], A[0, 3:] = p.k_x, -k_wheel * d[:, 0]
    A[1, 1], A[1, 3:] = p.k_y, -k_wheel * d[:, 1]
    A[2, 2], A[2, 3:] = p.k_theta, -k_wheel * p.l
    A[3:, 0:2] = k_wheel * d
    A[3:, 2] = k_wheel * p.l
    A[3:, 3:] = p.resistance_ohm * np.eye(3)
    return np.linalg.solve(A, np.concatenate((np.zeros(3), U)))


@pytest.mark.parametrize(
    "U",
    [np.array([0.0, 9.0, -9.0]), np.array([-6.0, 3.0, 3.0]), np.array([5.0, 5.0, 5.0])],
    ids=["translate", "translate-other", "spin"],
)
def test_constant_voltages_reach_the_analytical_steady_state(U):
    theta0 = 0.7
    plant = RobotinoPlant(ROBOT, np.array([0, 0, 0, 0, theta0, 0, 0, 0, 0.0]))
    for _ in range(600):  # 6 s, about 30 mechanical time constants
        plant.step(U, DT)
    theta = plant.pose[2]
    if U.sum() == 0.0:
        assert theta == pytest.approx(theta0, abs=1e-12)  # the summed current never moves
    expected = steady_state(ROBOT, U, theta)
    got = plant.state[[1, 3, 5, 6, 7, 8]]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    assert np.abs(expected).max() > 0.1


def test_energy_balance():
    # Input energy = stored (kinetic + magnetic) + dissipated (friction + copper), integrated finely.
    p = ROBOT
    fine = 100  # 0.1 ms samples against L / R = 1.5 ms: trapezoid error about 1e-4
    dt = DT / fine
    U = np.repeat(rich_voltages(20, seed=5, bias=3.0), fine, axis=0)
    plant = RobotinoPlant(p, STATE0)
    states = [plant.state]
    for u in U:
        plant.step(u, dt)
        states.append(plant.state)
    s = np.array(states)
    v2, w2, i = s[:, 1] ** 2 + s[:, 3] ** 2, s[:, 5] ** 2, s[:, 6:9]

    def stored(k):
        return 0.5 * p.M * v2[k] + 0.5 * p.J * w2[k] + 0.5 * p.inductance_h * np.sum(i[k] ** 2)

    def trapezoid(values):
        return float(np.sum(0.5 * (values[1:] + values[:-1])) * dt)

    power_in = np.einsum("kj,kj->k", U, 0.5 * (i[1:] + i[:-1]))
    friction = p.k_x * s[:, 1] ** 2 + p.k_y * s[:, 3] ** 2 + p.k_theta * w2
    dissipated = friction + p.resistance_ohm * np.sum(i**2, axis=1)
    energy_in = float(np.sum(power_in) * dt)
    balance = energy_in - (stored(-1) - stored(0)) - trapezoid(dissipated)
    assert abs(energy_in) > 1.0
    assert abs(balance) < 1e-3 * abs(energy_in)


def test_wheel_speeds_are_the_derivative_of_the_wheel_angles():
    plant = RobotinoPlant(ROBOT, STATE0)
    plant.step(np.array([4.0, -2.0, 1.0]), DT)
    a0, w0 = plant.wheel_angles, plant.wheel_speeds
    h = 1e-6
    plant.step(np.array([4.0, -2.0, 1.0]), h)
    np.testing.assert_allclose((plant.wheel_angles - a0) / h, w0, rtol=1e-4)
    # rim speed / r with the heading along the body: a pure spin turns every wheel at l theta' / r
    spin = RobotinoPlant(ROBOT, np.array([0, 0, 0, 0, 0.3, 2.0, 0, 0, 0.0]))
    np.testing.assert_allclose(spin.wheel_speeds, np.full(3, ROBOT.l * 2.0 / ROBOT.r))


def test_odometry_noise_and_body_twist():
    state = np.array([1.0, 0.0, 2.0, 1.0, 0.5 * np.pi, 0.3, 0.0, 0.0, 0.0])
    plant = RobotinoPlant(ROBOT, state)
    pose, twist = plant.odometry()
    np.testing.assert_array_equal(pose, [1.0, 2.0, 0.5 * np.pi])
    # Heading +y, moving along +y: forward in the robot frame.
    np.testing.assert_allclose(twist, [1.0, 0.0, 0.3], atol=1e-15)
    rng = np.random.default_rng(7)
    samples = np.array([plant.odometry(rng, (1e-3, 2e-3))[0] for _ in range(4000)])
    std = samples.std(axis=0)
    np.testing.assert_allclose(std, [1e-3, 1e-3, 2e-3], rtol=0.06)
    np.testing.assert_allclose(samples.mean(axis=0), [1.0, 2.0, 0.5 * np.pi], atol=2e-4)
    # The plant's own generator is seeded: equal seeds, equal noise.
    a = RobotinoPlant(ROBOT, state, seed=3).odometry(noise_std=(1e-3, 1e-3))[0]
    b = RobotinoPlant(ROBOT, state, seed=3).odometry(noise_std=(1e-3, 1e-3))[0]
    np.testing.assert_array_equal(a, b)


def test_reset_and_accessors():
    plant = RobotinoPlant(ROBOT)
    np.testing.assert_array_equal(plant.peak_abs_currents, 0.0)
    plant.step(np.array([3.0, 1.0, -2.0]), DT)
    assert plant.time_s > 0 and np.abs(plant.currents).max() > 0
    assert np.all(plant.peak_abs_currents >= np.abs(plant.currents))
    state = plant.state
    np.testing.assert_array_equal(plant.body_state, state[:6])
    np.testing.assert_array_equal(plant.pose, state[[0, 2, 4]])
    plant.reset(STATE0)
    assert plant.time_s == 0.0
    np.testing.assert_array_equal(plant.state, STATE0)
    np.testing.assert_array_equal(plant.wheel_angles, 0.0)
    np.testing.assert_array_equal(plant.peak_abs_currents, np.abs(STATE0[6:9]))


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda p: p.step([1.0, 2.0], DT), "voltages"),
        (lambda p: p.step([1.0, np.nan, 2.0], DT), "voltages"),
        (lambda p: p.step(["a", 1.0, 2.0], DT), "voltages"),
        (lambda p: p.step([1.0, 2.0, 3.0], 0.0), "dt"),
        (lambda p: p.step([1.0, 2.0, 3.0], float("nan")), "dt"),
        (lambda p: p.reset(np.zeros(6)), "state0"),
        (lambda p: p.reset(np.full(9, np.inf)), "state0"),
        (lambda p: p.odometry(noise_std=(-1.0, 0.0)), "noise_std"),
        (lambda p: p.odometry(noise_std=(1.0,)), "noise_std"),
        (lambda p: p.pose_noise(None, (0.0, -1e-3)), "noise_std"),
        (lambda p: RobotinoPlant(ROBOT, substeps=0), "substeps"),
    ],
)
def test_bad_inputs_raise(call, match):
    with pytest.raises(PlantError, match=match):
        call(RobotinoPlant(ROBOT))


def test_substep_currents_and_float_accessors():
    # The substep currents against the reference's samples at the substep ends; the float
    # accessors against the arrays, and tuple voltages against array voltages.
    U = rich_voltages(10, seed=6)
    _, fine = reference_run(ROBOT, STATE0, U)
    plant, twin = RobotinoPlant(ROBOT, STATE0), RobotinoPlant(ROBOT, STATE0)
    np.testing.assert_array_equal(plant.substep_currents, [STATE0[6:9]])
    for k, u in enumerate(U):
        plant.step(tuple(u.tolist()), DT)
        twin.step(u, DT)
        np.testing.assert_allclose(plant.substep_currents, fine[k][:, 6:9], rtol=0, atol=2e-6)
        np.testing.assert_array_equal(np.abs(plant.substep_currents).max(axis=0), plant.peak_abs_currents)
        np.testing.assert_array_equal(plant.substep_currents[-1], plant.currents)
    np.testing.assert_array_equal(plant.state, twin.state)
    pose, twist = plant.odometry()
    assert all(type(v) is float for v in pose + twist)
    x, vx, y, vy, theta, omega = plant.body_state
    np.testing.assert_array_equal(pose, [x, y, theta])
    turn = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])  # R(-theta)
    np.testing.assert_allclose(twist, [*(turn @ [vx, vy]), omega], rtol=0, atol=1e-12)


@pytest.mark.parametrize("anisotropic", [False, True])
def test_generator_is_coupled_rhs_in_the_heading_frame(anisotropic):
    """The matrices the plant integrates exactly are model.coupled_rhs (and the wheel-angle rates), state by state.

    In the frame at the heading (planar pairs in the body frame, R(theta)^T times the odom pair) the drive
    directions are d_i(0); the frame's matrix at rest, applied there and rotated back, must give coupled_rhs.
    """
    p = replace(ROBOT, body_friction_y_n_s_per_m=3.0 * ROBOT.k_y) if anisotropic else ROBOT
    plant = RobotinoPlant(p)
    rng = np.random.default_rng(8)
    for _ in range(10):
        state, U = rng.normal(0.0, 1.0, 9) * [1, 0.5, 1, 0.5, 3, 2, 0.5, 0.5, 0.5], rng.uniform(-24, 24, 3)
        theta = state[4]
        c, s = np.cos(theta), np.sin(theta)
        turn, back = np.array([[c, s], [-s, c]]), np.array([[c, -s], [s, c]])  # R(theta)^T, R(theta)
        w = np.concatenate((state, rng.normal(0.0, 1.0, 3), U))
        w[[0, 2]], w[[1, 3]] = turn @ state[[0, 2]], turn @ state[[1, 3]]
        derivative = plant._frame_matrix(0.0, theta) @ w
        derivative[[0, 2]], derivative[[1, 3]] = back @ derivative[[0, 2]], back @ derivative[[1, 3]]
        expected = np.concatenate((coupled_rhs(state, U, p), wheel_rim_speeds(theta, state[[1, 3, 5]], p) / p.r))
        np.testing.assert_allclose(derivative[:12], expected, rtol=1e-12, atol=1e-9)
        np.testing.assert_array_equal(derivative[12:], 0.0)  # the voltages are held


def test_pose_noise_is_the_odometrys_draws_and_none_without_noise():
    plant = RobotinoPlant(ROBOT, np.array([0.3, 0.1, -0.2, 0.0, 0.4, 0.5, 0.0, 0.0, 0.0]))
    assert plant.pose_noise(np.random.default_rng(1), (0.0, 0.0)) is None
    noise = plant.pose_noise(np.random.default_rng(5), (1e-3, 2e-3))
    assert noise == tuple(np.random.default_rng(5).normal(0.0, (1e-3, 1e-3, 2e-3)).tolist())
    pose, _ = plant.odometry(np.random.default_rng(5), (1e-3, 2e-3))
    assert np.allclose(np.subtract(pose, plant.pose), noise, atol=1e-16)


def test_pose_is_the_state_pose_as_floats_and_a_copy():
    """The offline loop's per-tick record: x, y, theta of `state` as Python floats, detached from the plant."""
    plant = RobotinoPlant(ROBOT, state0=np.array([0.3, 0.1, -0.2, 0.4, 1.1, 0.5, 0.0, 0.0, 0.0]))
    plant.step((6.0, -3.0, 2.0), 0.01)
    got = plant.pose
    assert got == plant.state[[0, 2, 4]].tolist() and all(type(v) is float for v in got)
    got[0] = 99.0
    assert plant.pose[0] != 99.0
