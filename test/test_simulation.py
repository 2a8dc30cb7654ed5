"""Offline closed loop: tracking, currents against the reference's inverse dynamics, scenarios and seeds."""

import numpy as np
import pytest

from robotino_geom_mpc.model import dynamics as model
from robotino_geom_mpc.geometric.decoupling import DecouplingField
from robotino_geom_mpc.control.mpc import axis_dampings
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.scenarios import ScenarioError, get_scenario
from robotino_geom_mpc.offline.simulation import RunConfig, SimulationError, run_scenario

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def params():
    return load_params()


@pytest.fixture(scope="module")
def circle(params):
    robot, control = params
    return run_scenario(RunConfig("paper-circle", robot, control, duration_s=3.0))


def test_perfect_model_tracks_the_circle(params, circle):
    robot, control = params
    run = circle
    assert run.t.shape == (300,)
    np.testing.assert_allclose(run.t, np.arange(300) * control.period_s)
    np.testing.assert_allclose(run.reference, make_reference("paper-circle").position(run.t), atol=1e-15)
    error = np.hypot(*(run.pose[:, :2] - run.reference[:, :2]).T)
    assert error.max() < 1e-5  # 10 micrometres, with a 0.5 m circle under way
    assert np.abs(run.pose[:, 2]).max() < 1e-9  # theta decoupled
    assert np.abs(run.voltages).max() < robot.supply_voltage_v
    assert not run.flags["saturated"].any() and not run.flags["infeasible"].any()


def test_currents_are_those_of_the_references_inverse_dynamics(params, circle):
    """Tracking exactly, the body's acceleration is the reference's: F = T(theta_d) (acc_d + (k/M) vel_d)."""
    robot, control = params
    run = circle
    t_mid = run.t + 0.5 * control.period_s
    pos, vel, acc, _ = make_reference("paper-circle").sample(t_mid)
    field = DecouplingField(robot)
    forces = np.einsum("kij,kj->ki", field.field(pos[:, 2]), acc + axis_dampings(robot) * vel)
    expected = np.array([model.currents_from_forces(F, robot) for F in forces])
    # recorded: the largest |i| within each period (drive lag and the change over a period aside)
    scale = np.abs(expected).max()
    assert scale > 0.1
    np.testing.assert_allclose(run.currents, expected, atol=0.03 * scale)


def test_robustness_scenario_stays_bounded_and_is_reproducible(params):
    robot, control = params
    a = run_scenario(RunConfig("robustness", robot, control, duration_s=2.0, seed=3))
    b = run_scenario(RunConfig("robustness", robot, control, duration_s=2.0, seed=3))
    c = run_scenario(RunConfig("robustness", robot, control, duration_s=2.0, seed=4))
    np.testing.assert_array_equal(a.voltages, b.voltages)
    assert not np.array_equal(a.voltages, c.voltages)
    error = np.hypot(*(a.pose[:, :2] - a.reference[:, :2]).T)
    assert np.sqrt(np.mean(error[a.t >= 1.0] ** 2)) < 5e-3
    assert np.all(np.isfinite(a.currents)) and np.abs(a.voltages).max() <= robot.supply_voltage_v
    assert a.meta["odometry_noise"] == [1e-3, 1e-3]
    ctl = get_scenario("robustness").controller_model(robot)
    assert ctl.M == pytest.approx(1.2 * robot.mass_kg + 1.5 * robot.rotor_mass_equivalent_kg)
    assert ctl.k_x == pytest.approx(2.0 * robot.k_x)


def test_plant_robot_and_noise_options(params):
    robot, control = params
    heavy = robot.scaled(mass=1.1)
    run = run_scenario(RunConfig("point-to-point", robot, control, duration_s=0.5, plant_robot=heavy,
                                 odometry_noise=(0.0, 0.0)))
    assert run.meta["plant_params"] == "plant_robot" and run.t.shape == (50,)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"scenario": "square"}, ScenarioError, "unknown scenario 'square'"),
        ({"scenario": "robustnes"}, ScenarioError, "did you mean 'robustness'"),
        ({"duration_s": -1.0}, SimulationError, "duration_s"),
        ({"odometry_noise": (-1e-3, 0.0)}, SimulationError, "odometry_noise"),
        ({"odometry": "lidar"}, SimulationError, "odometry model"),
        ({"odometry": "encoders", "encoder_counts_per_rev": 0}, SimulationError, "counts_per_rev"),
        ({"odometry": "encoders", "wheel_slip_std": 2.0}, SimulationError, "slip_std"),
    ],
)
def test_bad_settings_raise(params, kwargs, error, match):
    robot, control = params
    args = {"scenario": "paper-circle", **kwargs}
    with pytest.raises(error, match=match):
        run_scenario(RunConfig(args.pop("scenario"), robot, control, **args))


def test_each_tick_measures_then_previews_then_steps(params, monkeypatch):
    """The documented per-tick order: the controller sees the true state (no noise) and preview(t_k)."""
    robot, control = params
    from robotino_geom_mpc.control import motion_controller as controller_module
    from robotino_geom_mpc.reference.trajectories import preview

    seen = []
    original = controller_module.MotionController.step

    def spy(self, X, Y_d, dt_s=None):
        seen.append((np.array(X), np.array(Y_d)))
        return original(self, X, Y_d, dt_s)

    monkeypatch.setattr(controller_module.MotionController, "step", spy)
    run = run_scenario(RunConfig("lemniscate", robot, control, duration_s=0.3, progress=True))
    reference = make_reference("lemniscate")
    assert len(seen) == len(run.t)
    for k, (X, Y_d) in enumerate(seen):
        np.testing.assert_allclose(Y_d, preview(reference, run.t[k], control.period_s, control.horizon), atol=1e-12)
        np.testing.assert_allclose(X[0::2], run.pose[k], atol=1e-15)


def test_encoder_odometry_is_what_the_controller_tracks(params, monkeypatch):
    """With encoders the controller sees the dead-reckoned pose (recorded as `odometry`), not the truth."""
    robot, control = params
    from robotino_geom_mpc.control import motion_controller as controller_module
    from robotino_geom_mpc.model.encoders import integrate_pose

    seen = []
    original = controller_module.MotionController.step

    def spy(self, X, Y_d, dt_s=None):
        seen.append(np.array(X))
        return original(self, X, Y_d, dt_s)

    monkeypatch.setattr(controller_module.MotionController, "step", spy)
    run = run_scenario(RunConfig("paper-circle", robot, control, duration_s=2.0, odometry="encoders"))
    X = np.array(seen)
    np.testing.assert_array_equal(X[:, 0::2], run.odometry)
    assert run.meta["odometry"] == "encoders" and run.meta["encoder_counts_per_rev"] == 2048
    np.testing.assert_array_equal(run.odometry[0], run.pose[0])  # starts at the true pose, at rest
    drift = np.hypot(*(run.odometry[:, :2] - run.pose[:, :2]).T)
    assert 0.0 < drift.max() < 1e-3
    # each pose is the previous one carried by the measured twist over one period (dead reckoning)
    c, s = np.cos(X[:, 4]), np.sin(X[:, 4])
    twist = np.c_[c * X[:, 1] + s * X[:, 3], -s * X[:, 1] + c * X[:, 3], X[:, 5]]
    for k in range(1, len(X)):
        np.testing.assert_allclose(integrate_pose(run.odometry[k - 1], twist[k], control.period_s), run.odometry[k],
                                   atol=1e-12)
    ideal = run_scenario(RunConfig("paper-circle", robot, control, duration_s=2.0))
    np.testing.assert_array_equal(ideal.odometry, ideal.pose)  # noise-free ideal odometry is the truth
