"""The study's fast paths against the paths they replace, computed here step by step.

* `EncoderOdometry.update` (Python floats) against the numpy functions of
  `robotino_geom_mpc.model.encoders` (`encoder_counts`, `wheel_speeds_from_counts`,
  `body_twist`, `integrate_pose`) applied to the plant's wheel angles, with slip;
* the run's pose noise drawn at once (`simulation.run_scenario`) against one
  `RobotinoPlant.pose_noise` draw per tick, bit for bit;
* the plant's matrices shared per process: plants of other parameters, or of
  the same, interleaved, step as a plant alone in a fresh process would.
"""

from __future__ import annotations

import pytest
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.model import plant as plant_module
from robotino_geom_mpc.model.encoders import (
    EncoderOdometry, body_twist, encoder_counts, integrate_pose, wheel_speeds_from_counts,
)
from robotino_geom_mpc.model.plant import RobotinoPlant

pytestmark = pytest.mark.ros

ROBOT, CONTROL = load_params()
TS = CONTROL.period_s


def _voltages(rng, n):
    """Random +-12 V steps held a few periods each: turning, accelerating, braking."""
    return np.repeat(rng.uniform(-12.0, 12.0, (n // 5 + 1, 3)), 5, axis=0)[:n]


def test_encoder_update_is_the_numpy_functions_step_by_step():
    rng = np.random.default_rng(3)
    plant = RobotinoPlant(ROBOT)
    cpr, slip = 512, 0.05
    odometry = EncoderOdometry(plant, cpr, slip, seed=9)
    slip_rng = np.random.default_rng((9, 1))  # the encoder's slip stream, drawn here again
    angles = plant.wheel_angles
    seen = angles.copy()
    counts = encoder_counts(seen, ROBOT.gear_ratio, cpr)
    pose = tuple(plant.pose)
    for U in _voltages(rng, 120):
        plant.step(U, TS)
        got_pose, got_twist = odometry.update()
        change = (plant.wheel_angles - angles) * (1.0 + slip * slip_rng.standard_normal(3))
        seen, angles = seen + change, plant.wheel_angles
        new_counts = encoder_counts(seen, ROBOT.gear_ratio, cpr)
        speeds = wheel_speeds_from_counts(new_counts - counts, TS, ROBOT.gear_ratio, cpr)
        twist = tuple(body_twist(speeds, ROBOT).tolist())
        pose, counts = integrate_pose(pose, twist, TS), new_counts
        np.testing.assert_array_equal(odometry._counts, counts)
        np.testing.assert_allclose(got_twist, twist, rtol=0.0, atol=1e-12)
        np.testing.assert_allclose(got_pose, pose, rtol=0.0, atol=1e-12)
        assert all(type(v) is float for v in got_pose + got_twist)
    assert max(abs(v) for v in got_twist) > 0.1  # the robot moved: the comparison saw counts change


def test_run_noise_is_one_pose_noise_draw_per_tick():
    noise, seed = (1.5e-3, 0.7e-3), 21
    data = run_scenario(RunConfig("paper-circle", ROBOT, CONTROL, duration_s=0.5, seed=seed, odometry_noise=noise))
    rng, plant = np.random.default_rng(seed), RobotinoPlant(ROBOT)
    per_tick = np.array([plant.pose_noise(rng, noise) for _ in range(data.n)])
    np.testing.assert_allclose(data.odometry - data.pose, per_tick, rtol=0.0, atol=1e-15)
    assert np.abs(per_tick).max() > 1e-4  # noise was drawn
    quiet = run_scenario(RunConfig("paper-circle", ROBOT, CONTROL, duration_s=0.5, seed=seed,
                                   odometry_noise=(0.0, 0.0)))
    np.testing.assert_array_equal(quiet.odometry, quiet.pose)


def _steps(robot, voltages):
    plant = RobotinoPlant(robot)
    out = []
    for U in voltages:
        plant.step(U, TS)
        out.append(np.concatenate((plant.state, plant.substep_currents.ravel())))
    return np.array(out)


def test_shared_matrices_are_those_of_each_plant(tmp_path):
    heavy = replace(ROBOT, mass_kg=1.5 * ROBOT.mass_kg, body_friction_y_n_s_per_m=2.0 * ROBOT.k_y)  # anisotropic
    voltages = _voltages(np.random.default_rng(4), 30)
    # Interleaved in this process (the shared matrices of both in use), against each alone in a fresh process.
    a, b, a2 = RobotinoPlant(ROBOT), RobotinoPlant(heavy), RobotinoPlant(ROBOT)
    rows = {name: [] for name in "ab"}
    for U in voltages:
        for name, plant in (("a", a), ("b", b)):
            plant.step(U, TS)
            rows[name].append(np.concatenate((plant.state, plant.substep_currents.ravel())))
        a2.step(-U, TS)  # the same matrices, other work arrays: must not disturb a
    assert (ROBOT, None, TS) in plant_module._SHARED and (heavy, None, TS) in plant_module._SHARED
    code = (
        "import sys, numpy as np; sys.path.insert(0, sys.argv[1]); from test_study_speed import _steps, _voltages, "
        "ROBOT; from dataclasses import replace; "
        "heavy = replace(ROBOT, mass_kg=1.5 * ROBOT.mass_kg, body_friction_y_n_s_per_m=2.0 * ROBOT.k_y); "
        "v = _voltages(np.random.default_rng(4), 30); "
        "np.save(sys.argv[2], np.stack((_steps(ROBOT, v), _steps(heavy, v))))"
    )
    path = tmp_path / "alone.npy"
    subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent), str(path)], check=True, timeout=120)
    alone = np.load(path)
    np.testing.assert_array_equal(np.array(rows["a"]), alone[0])
    np.testing.assert_array_equal(np.array(rows["b"]), alone[1])
    assert not np.array_equal(alone[0], alone[1])
