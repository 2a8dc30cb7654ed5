"""`robotino-geom-mpc study`: rows against direct runs, the summary against numpy, failing runs, reproducibility.

The truth of a row is `simulation.run_scenario` (the per-run float path) called here, in this process,
with the controller's model built field by field from the row's draws (not
through `RobotinoParams.scaled`), and `results.compute_metrics` of that run.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import replace

import matplotlib.image as mpimg
import numpy as np
import pytest

from robotino_geom_mpc.bench import REGISTRY
from robotino_geom_mpc.cli import main
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.offline.study import (
    COLUMNS, DRAW_FIELDS, METRICS, STATISTICS, Draw, StudyError, draw_runs, read_rows, run_study, write_study,
)

pytestmark = pytest.mark.ros

SAMPLES, SEED, DURATION_S = 6, 7, 2.0


@pytest.fixture(scope="module")
def params():
    return load_params()


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("study") / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "robotino_geom_mpc", "study", "--scenario", "paper-circle", "--samples", str(SAMPLES),
         "--workers", "2", "--seed", str(SEED), "--duration", str(DURATION_S), "--out", str(out), "--no-progress"],
        capture_output=True, text=True, timeout=300, env=dict(os.environ),
    )
    assert proc.returncode == 0, proc.stderr
    assert "aggregate real-time factor" in proc.stdout
    return out


def _direct(robot, control, row, scenario="paper-circle"):
    """The run of a row's draws, with the controller's model scaled here field by field."""
    model = replace(
        robot,
        mass_kg=robot.mass_kg * row["mass"],
        yaw_inertia_kg_m2=robot.yaw_inertia_kg_m2 * row["inertia"],
        body_friction_x_n_s_per_m=robot.body_friction_x_n_s_per_m * row["friction"],
        body_friction_y_n_s_per_m=robot.body_friction_y_n_s_per_m * row["friction"],
        body_friction_theta_n_m_s=robot.body_friction_theta_n_m_s * row["friction"],
    )
    data = run_scenario(RunConfig(scenario, model, control, duration_s=DURATION_S, seed=row["seed"], plant_robot=robot,
                                  odometry_noise=(row["noise_position_m"], row["noise_yaw_rad"]),
                                  odometry=row["odometry"]))
    return compute_metrics(data, settle_time_s=1.0)


def test_rows_are_the_draws_run_directly(study_dir, params):
    robot, control = params
    rows = read_rows(study_dir / "runs.csv")
    assert [row["index"] for row in rows] == list(range(SAMPLES))
    assert list(rows[0]) == list(COLUMNS)
    drawn = draw_runs(SAMPLES, SEED)
    for row, draw in zip(rows, drawn):
        assert {f: row[f] for f in DRAW_FIELDS} == vars(draw)  # full precision through the CSV
        assert 0.8 <= row["mass"] <= 1.2 and 0.8 <= row["inertia"] <= 1.2 and 0.5 <= row["friction"] <= 2.0
        assert 0.0 <= row["noise_position_m"] <= 2e-3 and 0.0 <= row["noise_yaw_rad"] <= 2e-3
        assert row["error"] == ""
        assert row["simulated_s"] == pytest.approx(DURATION_S, abs=1e-9)
        truth = _direct(robot, control, row)
        for key in METRICS:  # the study steps its runs together (array forms): equal to rounding
            assert row[key] == pytest.approx(truth[key], rel=0.0, abs=1e-9), key
    # the draws reach the controller: the same seed and noise with the true model runs differently
    nominal = _direct(robot, control, {**rows[0], "mass": 1.0, "inertia": 1.0, "friction": 1.0})
    assert nominal["peak_voltage_v"] != pytest.approx(rows[0]["peak_voltage_v"], rel=1e-6)
    assert len({row["seed"] for row in rows}) == SAMPLES
    assert {row["odometry"] for row in rows} == {"ideal", "encoders"}


def test_summary_is_numpy_of_the_rows(study_dir):
    rows = read_rows(study_dir / "runs.csv")
    summary = json.loads((study_dir / "summary.json").read_text())
    assert summary["runs"] == SAMPLES and summary["failed_runs"] == 0
    assert summary["simulated_s"] == pytest.approx(SAMPLES * DURATION_S)
    assert summary["aggregate_realtime_factor"] == pytest.approx(summary["simulated_s"] / summary["wall_s"])
    # the study's wall time covers its runs: at least the longest one
    assert summary["wall_s"] >= max(row["wall_s"] for row in rows)
    for key in STATISTICS:
        values = np.array([row[key] for row in rows])
        assert summary[key]["median"] == pytest.approx(np.median(values), rel=1e-12)
        assert summary[key]["p95"] == pytest.approx(np.percentile(values, 95), rel=1e-12)
        assert summary[key]["worst"] == max(values)
        worst = rows[int(np.argmax(values))]
        assert summary["worst_runs"][key] == {f: worst[f] for f in DRAW_FIELDS}
    assert summary["nominal_current_a"] == pytest.approx(0.86)
    assert "histograms.png" in summary["figures"] and "worst_peak_current_a/currents.png" in summary["figures"]
    for figure in summary["figures"]:
        assert mpimg.imread(study_dir / figure).ndim == 3


def test_a_failing_run_is_a_row_with_its_error(params, tmp_path):
    robot, control = params
    bad = Draw(index=2, seed=0, mass=1.0, inertia=1.0, friction=1.0, noise_position_m=-1.0, noise_yaw_rad=0.0,
               odometry="ideal")
    result = run_study("paper-circle", robot, control, draw_runs(2, 3) + [bad], duration_s=1.0, workers=2,
                       progress=False)
    assert [row["index"] for row in result.rows] == [0, 1, 2]
    failed = result.rows[2]
    assert failed["error"].startswith("SimulationError: odometry_noise")
    assert failed["simulated_s"] == 0.0 and all(failed[key] is None for key in METRICS)
    assert all(row["error"] == "" and math.isfinite(row["peak_current_a"]) for row in result.rows[:2])
    summary = write_study(tmp_path, "paper-circle", robot, control, result, duration_s=1.0)
    assert summary["runs"] == 3 and summary["failed_runs"] == 1
    assert summary["simulated_s"] == pytest.approx(2.0)
    assert summary["peak_current_a"]["worst"] == max(row["peak_current_a"] for row in result.rows[:2])
    assert summary["rms_position_error_m"] is None  # 1 s runs end at the settle time: no position error counted
    assert read_rows(tmp_path / "runs.csv")[2]["error"] == failed["error"]
    # a study whose every run fails still writes its summary
    only_bad = run_study("paper-circle", robot, control, [bad], duration_s=1.0, workers=1, progress=False)
    summary = write_study(tmp_path / "bad", "paper-circle", robot, control, only_bad)
    assert summary["failed_runs"] == 1 and summary["peak_current_a"] is None and summary["figures"] == []
    assert summary["worst_runs"] == {key: None for key in STATISTICS}


def test_same_seed_same_rows(params):
    robot, control = params
    assert draw_runs(5, 11) == draw_runs(5, 11)
    assert draw_runs(5, 11) != draw_runs(5, 12)
    assert {d.odometry for d in draw_runs(5, 11, ("encoders",))} == {"encoders"}

    def rows(workers):
        result = run_study("robustness", robot, control, draw_runs(3, 11), duration_s=1.0, workers=workers,
                           progress=False)
        return [{k: v for k, v in row.items() if k != "wall_s"} for row in result.rows]

    assert rows(2) == rows(1)


def test_bad_settings_are_refused(params, capsys):
    robot, control = params
    for argv in (["--samples", "0"], ["--samples", "2", "--workers", "0"], ["--samples", "x"]):
        with pytest.raises(SystemExit) as exc:
            main(["study", "--scenario", "paper-circle", "--out", "unused", *argv])
        assert exc.value.code == 2
    assert "--samples" in capsys.readouterr().err
    with pytest.raises(StudyError, match="samples"):
        draw_runs(0, 1)
    with pytest.raises(StudyError, match="odometry"):
        draw_runs(2, 1, ("wheels",))
    with pytest.raises(StudyError, match="workers"):
        run_study("paper-circle", robot, control, draw_runs(1, 1), workers=0)
    with pytest.raises(StudyError, match="draw"):
        run_study("paper-circle", robot, control, [])


@pytest.mark.slow
def test_bench_study_figures():
    figures = REGISTRY["study"].func(True)
    assert figures["study_failed_runs"] == 0.0 and figures["study_runs"] == 64
    assert figures["study_aggregate_realtime_factor"] == pytest.approx(64 * 5.0 / figures["study_wall_s"], rel=1e-9)
    assert figures["study_batched_speedup_vs_per_run"] == pytest.approx(
        figures["study_aggregate_realtime_factor"] / figures["study_per_run_aggregate_realtime_factor"], rel=1e-12)
    assert figures["batched_cpu_speedup_vs_per_run"] == pytest.approx(
        figures["per_run_us_per_tick"] / figures["batched_us_per_run_tick"], rel=1e-12)
