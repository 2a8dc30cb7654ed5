"""Each batch kernel (`DecoupledMPCBatch`, `DecouplingFieldBatch`, `MotorKinematicsBatch`, `InverseDriveBatch`,
`OdometryFilterBatch`, `PlantBatch`) against its one-run class run by run, for runs with different parameters.

The one-run classes are checked against independent truths in their own tests (test_mpc, test_decoupling,
test_drive, test_estimator, test_plant); here each run of a batch must give its own class's numbers (to rounding,
1e-12 relative), on the unclipped, the clipped and the current-limited paths of the drive.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from robotino_geom_mpc.control.estimator import OdometryFilter, OdometryFilterBatch
from robotino_geom_mpc.control.inverse_drive import InverseDrive, InverseDriveBatch
from robotino_geom_mpc.control.mpc import DecoupledMPC, DecoupledMPCBatch
from robotino_geom_mpc.geometric.decoupling import DecouplingField, DecouplingFieldBatch
from robotino_geom_mpc.model.kinematics import MotorKinematics, MotorKinematicsBatch
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.plant_batch import PlantBatch
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit
RTOL = 1e-12


@pytest.fixture(scope="module")
def params():
    return load_params()


def _robots(robot):
    """Three runs whose every batched quantity differs: masses, inertia, friction, wheels, motors, supply."""
    return [
        robot,
        replace(robot.scaled(mass=1.2, inertia=0.8, friction=1.7), wheel_radius_m=1.1 * robot.wheel_radius_m,
                wheel_distance_m=0.9 * robot.wheel_distance_m, resistance_ohm=1.3 * robot.resistance_ohm),
        replace(robot.scaled(mass=0.85, inertia=1.15, friction=0.6), inductance_h=2.0 * robot.inductance_h,
                supply_voltage_v=0.5 * robot.supply_voltage_v, gear_ratio=1.2 * robot.gear_ratio),
    ]


def test_mpc_batch_is_each_runs_mpc(params):
    robot, control = params
    robots = _robots(robot)
    batch = DecoupledMPCBatch(robots, control)
    rng = np.random.default_rng(1)
    X, u_prev = rng.normal(size=(3, 6)), rng.normal(size=(3, 3))
    shared, own = rng.normal(size=(control.horizon, 3)), rng.normal(size=(3, control.horizon, 3))
    for b, p in enumerate(robots):
        one = DecoupledMPC(p, control)
        for name in ("A_d", "B_d", "G_p", "F_1p", "F_2p", "gain", "stacked_gain", "prediction_map"):
            np.testing.assert_allclose(getattr(batch, name)[b], getattr(one, name), rtol=RTOL, atol=1e-13, err_msg=name)
        for Y_d, run in ((shared, shared), (own, own[b])):
            floats = one.delta_u(X[b].tolist(), u_prev[b].tolist(), run.tolist())
            np.testing.assert_allclose(batch.delta_u(X, u_prev, Y_d)[b], floats, rtol=RTOL, atol=1e-12)


def test_field_batch_is_each_runs_field(params):
    robots = _robots(params[0])
    rng = np.random.default_rng(2)
    theta, u = rng.uniform(-np.pi, np.pi, 3), rng.normal(size=(3, 3))
    forces = DecouplingFieldBatch(robots).forces(theta, u)
    for b, p in enumerate(robots):
        one = DecouplingField(p)
        np.testing.assert_allclose(forces[b], one.forces(float(theta[b]), u[b].tolist()), rtol=RTOL)
        np.testing.assert_allclose(forces[b], one.field(theta[b]) @ u[b], rtol=RTOL)


@pytest.mark.parametrize("shared_wheels", [True, False])
def test_kinematics_batch_is_each_runs_kinematics(params, shared_wheels):
    robot = params[0]
    robots = [robot.scaled(mass=1.3), robot, robot.scaled(friction=2.0)] if shared_wheels else _robots(robot)
    batch = MotorKinematicsBatch(robots)
    assert batch.W0.shape == ((3, 3) if shared_wheels else (3, 3, 3))  # one W(0) for runs with the same wheels
    rng = np.random.default_rng(3)
    theta, v, a = rng.uniform(-np.pi, np.pi, 3), rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    omega, rate = batch.speeds_and_rates(theta, v, a)
    for b, p in enumerate(robots):
        floats = MotorKinematics(p).speeds_and_rates(float(theta[b]), v[b].tolist(), a[b].tolist())
        np.testing.assert_allclose(omega[b], floats[0], rtol=RTOL)
        np.testing.assert_allclose(rate[b], floats[1], rtol=RTOL)


@pytest.mark.parametrize("limit", [0.0, 1.5])
def test_drive_batch_is_each_runs_drive(params, limit):
    """Three periods: commands the runs keep, then commands that clip (and, with a limit, that get scaled)."""
    robot, control = params
    robots = _robots(robot)
    batch = InverseDriveBatch(robots, control.period_s)
    ones = [InverseDrive(p, control.period_s) for p in robots]
    rng = np.random.default_rng(4)
    saturated_seen = scaled_seen = False
    for size in (0.2, 6.0, 3.0):
        i_cmd, omega, rate = size * rng.normal(size=(3, 3)), 30.0 * rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
        rest = 0.3 * rng.normal(size=(3, 3))
        rate_of_current = lambda i: 2.0 * np.asarray(i) - 0.5  # noqa: E731  (a stand-in map, the same for all)
        if limit:
            U, saturated, mean, scale = batch.limited_step(i_cmd, omega, rate, lambda: rest, limit, rate_of_current)
            scaled_seen |= bool((scale < 1.0).any())
        else:
            U, saturated, mean = batch.step(i_cmd, omega, rate, rate_of_current)
        saturated_seen |= bool(saturated.any())
        for b, one in enumerate(ones):
            if limit:
                Ub, sb, mb, kb = one.limited_step(i_cmd[b].tolist(), omega[b].tolist(), rate[b].tolist(),
                                                  lambda b=b: rest[b].tolist(), limit, rate_of_current)
                assert scale[b] == pytest.approx(kb, rel=RTOL)
            else:
                Ub, sb, mb = one.step(i_cmd[b].tolist(), omega[b].tolist(), rate[b].tolist(), rate_of_current)
            assert saturated[b] == sb
            np.testing.assert_allclose(U[b], Ub, rtol=RTOL, atol=1e-12)
            np.testing.assert_allclose(mean[b], mb, rtol=RTOL, atol=1e-12)
            np.testing.assert_allclose(batch.current_estimate[b], one.current_estimate, rtol=RTOL, atol=1e-12)
    assert scaled_seen if limit else saturated_seen  # the scaled (the clipped) path was taken


def test_filter_batch_is_each_runs_filter(params):
    control = params[1]
    twists = ["instantaneous", "period_mean", "period_mean"]
    rng = np.random.default_rng(5)
    start = rng.normal(size=(3, 3))
    batch = OdometryFilterBatch(control.period_s, 0.5, twists, start)
    ones = [OdometryFilter(control.period_s, 0.5, twist) for twist in twists]
    for one, pose in zip(ones, start):
        one.start_at(*pose.tolist())
    for k in range(20):
        X = rng.normal(size=(3, 6))
        X[2, 5] = 1e-8 if k % 2 else X[2, 5]  # the period mean's series for a small turn, in one run only
        estimates = batch.update(X)
        for b, one in enumerate(ones):
            np.testing.assert_allclose(estimates[b], one.update(*X[b].tolist()), rtol=RTOL, atol=1e-13)


def test_plant_batch_is_each_runs_plant(params):
    """50 periods of held voltages, a turning run among them (the fast path's heading polynomial) and an
    anisotropic one (k_y = 1.7 k_x: the exact maps): every run's state and odometry as its own `RobotinoPlant`'s.
    """
    robot, control = params
    robots = [*_robots(robot)[:2], replace(robot, body_friction_y_n_s_per_m=1.7 * robot.body_friction_y_n_s_per_m)]
    batch, ones = PlantBatch(robots), [RobotinoPlant(p) for p in robots]
    rng = np.random.default_rng(6)
    turning = np.array([[4.0, 4.0, 4.0], [0.0, 0.0, 0.0], [3.0, -2.0, -1.0]])  # run 0 spins, run 2 drives
    for _ in range(50):
        U = turning + rng.normal(0.0, 1.0, (3, 3))
        batch.step(U, control.period_s)
        for b, one in enumerate(ones):
            one.step(U[b], control.period_s)
    pose, twist = batch.odometry()
    assert abs(ones[0].state[5]) > 1.0  # the spinning run turns at more than 1 rad/s
    for b, one in enumerate(ones):
        np.testing.assert_allclose(batch.state[b, :9], one.state, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(batch.wheel_angles[b], one.wheel_angles, rtol=1e-12, atol=1e-12)
        one_pose, one_twist = one.noisy_odometry(None)
        np.testing.assert_allclose(pose[b], one_pose, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(twist[b], one_twist, rtol=1e-12, atol=1e-12)
