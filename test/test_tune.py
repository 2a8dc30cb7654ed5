"""`robotino-geom-mpc tune`: its files against independent recomputations.

The truth of a figure is a study recomputed here run by run (`study.run_one`,
the per-run float path, not the batched loop the tuning uses) and numpy's
percentiles of its rows; the parameter file is checked by the nodes' own file
check, read back, and run by ``simulate --params``.
"""

from __future__ import annotations

import csv
import json
import math

import matplotlib.image as mpimg
import numpy as np
import pytest

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.offline.study import draw_runs, run_one
from robotino_geom_mpc.offline.tune import HELD_OUT_SEED_OFFSET, score_study
from robotino_geom_mpc.params.files import NODE_PARAMETERS, check_parameter_files, load_params, read_parameter_file
from robotino_geom_mpc.system.processes import node_arguments

pytest.importorskip("optuna", reason="the tune extra: pip install '.[tune]'")
pytestmark = [pytest.mark.ros, pytest.mark.slow]

SCENARIO, SAMPLES, TRIALS, SEED, DURATION_S = "robustness", 5, 4, 3, 1.5


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune")
    status = main(["tune", "--scenario", SCENARIO, "--samples", str(SAMPLES), "--trials", str(TRIALS), "--seed",
                   str(SEED), "--duration", str(DURATION_S), "--workers", "2", "--out", str(out), "--no-progress"])
    return out, status


def _recomputed(control, seed):
    robot, _ = load_params()
    rows = [run_one(SCENARIO, robot, control, draw, DURATION_S, 1.0) for draw in draw_runs(SAMPLES, seed)]
    rms = [row["rms_position_error_m"] for row in rows]
    peaks = [row["peak_current_a"] for row in rows]
    return float(np.percentile(rms, 95)), float(np.percentile(peaks, 99))


def test_trials_and_best_parameters(tuned):
    out, status = tuned
    robot, base = load_params()
    with open(out / "trials.csv", newline="") as stream:
        trials = list(csv.DictReader(stream))
    assert [int(t["trial"]) for t in trials] == list(range(TRIALS))
    first = trials[0]  # the base weights start the search
    assert [float(first[f"q_{a}"]) for a in ("x", "y", "theta")] == pytest.approx(list(base.q), rel=1e-12)
    assert int(first["horizon"]) == base.horizon
    check_parameter_files([out / "params.yaml"])
    _, control = load_params(out / "params.yaml")
    feasible = [t for t in trials if t["feasible"] == "True"]
    best = min(feasible, key=lambda t: float(t["p95_rms_position_error_m"]))
    assert list(control.q) == pytest.approx([float(best[f"q_{a}"]) for a in ("x", "y", "theta")], rel=1e-12)
    assert control.horizon == int(best["horizon"]) and list(control.r) == list(base.r)
    p95, p99 = _recomputed(control, SEED)  # the trial's objective and constraint, run by run
    assert float(best["p95_rms_position_error_m"]) == pytest.approx(p95, rel=0.0, abs=1e-9)
    assert float(best["p99_peak_current_a"]) == pytest.approx(p99, rel=0.0, abs=1e-9)
    assert p99 <= robot.nominal_current_a
    assert mpimg.imread(out / "objective.png").ndim == 3


def test_certificate_is_the_held_out_study(tuned):
    out, status = tuned
    robot, base = load_params()
    certificate = json.loads((out / "certificate.json").read_text())
    assert certificate["held_out_seed"] == SEED + HELD_OUT_SEED_OFFSET
    _, control = load_params(out / certificate["params_file"])
    for side, settings in (("tuned", control), ("default", base)):
        p95, p99 = _recomputed(settings, SEED + HELD_OUT_SEED_OFFSET)
        assert certificate[side]["p95_rms_position_error_m"] == pytest.approx(p95, rel=0.0, abs=1e-9)
        assert certificate[side]["p99_peak_current_a"] == pytest.approx(p99, rel=0.0, abs=1e-9)
    passed = (certificate["tuned"]["p95_rms_position_error_m"] <= certificate["default"]["p95_rms_position_error_m"]
              and certificate["tuned"]["p99_peak_current_a"] <= robot.nominal_current_a)
    assert certificate["passed"] is passed and status == (0 if passed else 1)


def test_the_parameter_file_runs_unchanged(tuned, tmp_path):
    """``run --params`` takes the file as it is: rcl's reading and the nodes' check pass, every node of the run
    gets it as its ``--params-file``, the controller reads the tuned weights from it; ``simulate --params`` runs it.
    """
    out, _ = tuned
    path = out / "params.yaml"
    check_parameter_files([path])  # what `run` and each node check before starting (rcl's reading included)
    _, control = load_params(path)
    for executable, argv in node_arguments(SCENARIO, path, 1.0, lockstep=True).items():
        assert argv[argv.index("--params-file") + 1] == str(path), executable
    values = read_parameter_file(path, "robotino_controller")
    assert [values[f"control.q_{a}"] for a in ("x", "y", "theta")] == list(control.q)
    assert values["control.horizon"] == control.horizon
    assert set(values) <= set(NODE_PARAMETERS["robotino_controller"]) | {"use_sim_time"}
    assert main(["simulate", "--scenario", "paper-circle", "--duration", "1.5", "--params", str(out / "params.yaml"),
                 "--out", str(tmp_path / "sim"), "--no-plots"]) == 0
    metrics = json.loads((tmp_path / "sim" / "metrics.json").read_text())
    assert math.isfinite(metrics["rms_position_error_m"])


def test_score_is_numpy_percentiles_and_a_failed_run_counts_as_worst():
    rows = [{"error": "", "rms_position_error_m": v, "peak_current_a": 2 * v} for v in (1.0, 2.0, 3.0)]
    score = score_study(rows + [{"error": "SimulationError: x", "rms_position_error_m": None, "peak_current_a": None}])
    assert score.failed_runs == 1
    assert score.p95_rms_position_error_m == math.inf and score.p99_peak_current_a == math.inf
    score = score_study(rows)
    assert score.p95_rms_position_error_m == pytest.approx(np.percentile([1.0, 2.0, 3.0], 95), rel=1e-15)
    assert score.p99_peak_current_a == pytest.approx(np.percentile([2.0, 4.0, 6.0], 99), rel=1e-15)
