"""The batched closed loop (`offline.batch_simulation.run_batch`) against each run's own `run_scenario`.

The truth of every run is `simulation.run_scenario` on the per-tick float path
(the nodes' path), called here run by run; the batch steps the same runs
together through the array forms. A batch draws runs of every kind: ideal and
encoder odometry (with and without slip), noise and none, controller models off
the truth, two different plants (one with anisotropic friction, whose substeps
take the exact expm maps), the current limit on and off, the pose filter on and
off (saturated voltages and their fixed point), several scenarios.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from robotino_geom_mpc.control.estimator import EstimatorError
from robotino_geom_mpc.control.motion_batch import BatchControlError, MotionControllerBatch
from robotino_geom_mpc.model.plant import PlantError
from robotino_geom_mpc.model.plant_batch import PlantBatch
from robotino_geom_mpc.offline import batch_simulation
from robotino_geom_mpc.offline.batch_simulation import RunSetting, batch_metrics, run_batch, simulate_batch
from robotino_geom_mpc.offline.results import RunDataError, compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, SimulationError, run_scenario
from robotino_geom_mpc.params.files import load_params

pytestmark = [pytest.mark.unit, pytest.mark.slow]
TOLERANCE = 1e-9


@pytest.fixture(scope="module")
def params():
    return load_params()


def _settings(robot, count: int, seed: int, anisotropic: bool = False) -> list[RunSetting]:
    """`count` runs of every kind, drawn from `seed`; with `anisotropic`, every third plant has k_y = 1.7 k_x."""
    rng = np.random.default_rng(seed)
    other = replace(robot, body_friction_y_n_s_per_m=1.7 * robot.body_friction_y_n_s_per_m) if anisotropic \
        else replace(robot, mass_kg=1.1 * robot.mass_kg)
    settings = []
    for k in range(count):
        odometry = ("ideal", "encoders")[k % 2]
        settings.append(RunSetting(
            robot=robot.scaled(mass=rng.uniform(0.8, 1.2), inertia=rng.uniform(0.8, 1.2),
                               friction=float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))),
            plant_robot=(robot, other, None)[k % 3],
            seed=int(rng.integers(0, 2**31)),
            odometry_noise=None if k % 4 == 3 else tuple(rng.uniform(0.0, 2e-3, 2)),
            odometry=odometry,
            encoder_counts_per_rev=(2048, 500)[k % 2],
            wheel_slip_std=0.02 if k % 4 == 1 else 0.0,
        ))
    return settings


def _assert_equal_runs(batch, settings, scenario, control, duration_s):
    for data, s in zip(batch, settings, strict=True):
        truth = run_scenario(RunConfig(scenario, s.robot, control, duration_s=duration_s, seed=s.seed,
                                       plant_robot=s.plant_robot, odometry_noise=s.odometry_noise,
                                       odometry=s.odometry, encoder_counts_per_rev=s.encoder_counts_per_rev,
                                       wheel_slip_std=s.wheel_slip_std))
        expected, got = compute_metrics(truth), compute_metrics(data)
        timing = {"compute_time_median_s", "compute_time_p99_s", "compute_time_max_s"}  # wall clock: no truth
        assert set(got) - timing == set(expected) - timing
        for key, value in got.items():
            if key in timing:
                continue
            if isinstance(value, float):
                assert value == pytest.approx(expected[key], rel=0.0, abs=TOLERANCE), (key, s)
            else:
                assert value == expected[key], (key, s)
        for name in ("pose", "odometry", "voltages", "currents"):
            np.testing.assert_allclose(getattr(data, name), getattr(truth, name), rtol=0.0, atol=TOLERANCE)
        assert data.meta == truth.meta


@pytest.mark.parametrize("scenario, limited, seed", [
    ("paper-circle", True, 1),
    ("robustness", False, 3),  # no current limit, no pose filter: 1 mm noise saturates the voltages
    ("lemniscate", True, 4),
])
def test_batch_equals_each_run(params, scenario, limited, seed):
    robot, control = params
    if not limited:
        control = replace(control, current_limit_a=0.0, odometry_filter_time_constant_s=0.0)
    settings = _settings(robot, 8, seed)
    batch = run_batch(scenario, control, settings, duration_s=1.0)
    _assert_equal_runs(batch, settings, scenario, control, 1.0)
    if not limited:
        assert sum(int(d.flags["saturated"].sum()) for d in batch) > 0  # the clipped path was taken


def test_anisotropic_plant_takes_the_exact_maps(params):
    robot, control = params
    settings = _settings(robot, 3, 6, anisotropic=True)
    _assert_equal_runs(run_batch("robustness", control, settings, duration_s=0.3), settings, "robustness", control,
                       0.3)


def test_one_run_batch_is_run_scenario(params):
    robot, control = params
    settings = _settings(robot, 1, 9)
    _assert_equal_runs(run_batch("paper-circle", control, settings, duration_s=1.0), settings, "paper-circle",
                       control, 1.0)


def test_constrained_mode_is_routed_per_run(params):
    robot, control = params
    control = replace(control, mode="constrained")
    settings = _settings(robot, 2, 5)
    batch = run_batch("paper-circle", control, settings, duration_s=0.5)
    _assert_equal_runs(batch, settings, "paper-circle", control, 0.5)
    assert all(data.compute_time_s is not None for data in batch)  # run_scenario's own runs


def test_bad_settings_are_refused(params):
    robot, control = params
    with pytest.raises(SimulationError, match="at least one run"):
        run_batch("paper-circle", control, [])
    with pytest.raises(SimulationError, match="odometry_noise"):
        run_batch("paper-circle", control, [RunSetting(robot, odometry_noise=(-1.0, 0.0))])
    with pytest.raises(SimulationError, match="odometry model"):
        run_batch("paper-circle", control, [RunSetting(robot, odometry="gps")])
    with pytest.raises(SimulationError, match="duration_s"):
        run_batch("paper-circle", control, [RunSetting(robot)], duration_s=-1.0)
    with pytest.raises(PlantError, match="voltages"):
        PlantBatch([robot, robot]).step(np.array([[0.0, np.nan, 0.0], [0.0, 0.0, 0.0]]), 0.01)
    with pytest.raises(PlantError, match="dt"):
        PlantBatch([robot]).step(np.zeros((1, 3)), 0.0)
    with pytest.raises(BatchControlError, match="closed-form"):
        MotionControllerBatch([robot], replace(control, mode="constrained"), ["instantaneous"], np.zeros((1, 3)))
    with pytest.raises(EstimatorError, match="twists"):
        MotionControllerBatch([robot], control, ["sometimes"], np.zeros((1, 3)))


@pytest.mark.parametrize("settle_time_s", [0.4, 5.0])  # 5 s: no sample after the settle time, None metrics
def test_batch_metrics_are_each_runs_compute_metrics(params, settle_time_s, monkeypatch):
    """`BatchSeries.metrics` (the study's path) against `compute_metrics` of each run's own `run_scenario`."""
    monkeypatch.setattr(batch_simulation, "_METRIC_CHUNK", 4)  # two chunks of runs
    robot, control = params
    settings = _settings(robot, 6, 11)
    got = batch_metrics("robustness", control, settings, duration_s=1.0, settle_time_s=settle_time_s)
    for metrics, s in zip(got, settings, strict=True):
        truth = run_scenario(RunConfig("robustness", s.robot, control, duration_s=1.0, seed=s.seed,
                                       plant_robot=s.plant_robot, odometry_noise=s.odometry_noise,
                                       odometry=s.odometry, encoder_counts_per_rev=s.encoder_counts_per_rev,
                                       wheel_slip_std=s.wheel_slip_std))
        expected = {key: value for key, value in compute_metrics(truth, settle_time_s=settle_time_s).items()
                    if not key.startswith("compute_time")}
        assert list(metrics) == list(expected)  # the same keys in the same order
        for key, value in expected.items():
            if isinstance(value, float):
                assert metrics[key] == pytest.approx(value, rel=0.0, abs=TOLERANCE), key
            else:
                assert metrics[key] == value and type(metrics[key]) is type(value), key
    with pytest.raises(RunDataError, match="settle_time_s"):
        simulate_batch("paper-circle", control, settings[:1], duration_s=0.1).metrics(-1.0)
