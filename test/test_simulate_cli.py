"""`robotino-geom-mpc simulate`: outputs of a short paper-circle run, and one-line errors with exit status 2."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import matplotlib.image as mpimg
import pytest

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.offline.plots import FIGURE_SIZES_IN
from robotino_geom_mpc.offline.results import METRIC_KEYS, compute_metrics, load_run, read_metrics

pytestmark = pytest.mark.ros


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "robotino_geom_mpc", *args],
        capture_output=True, text=True, timeout=300, env=dict(os.environ),
    )


@pytest.fixture(scope="module")
def circle_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("simulate") / "tmp"
    proc = _cli("simulate", "--scenario", "paper-circle", "--duration", "3", "--out", str(out), "--no-progress")
    return proc, out


def test_simulate_writes_metrics_and_figures(circle_run):
    proc, out = circle_run
    assert proc.returncode == 0, proc.stderr
    metrics = read_metrics(out / "metrics.json")
    for key in METRIC_KEYS:
        assert key in metrics, key
    assert metrics["scenario"] == "paper-circle"
    assert metrics["duration_s"] == pytest.approx(3.0, abs=2 * metrics["control_period_s"])
    assert metrics["settle_time_s"] == 1.0
    for key in ("rms_position_error_m", "max_position_error_m", "peak_current_a", "peak_voltage_v"):
        assert math.isfinite(metrics[key]) and metrics[key] >= 0.0
    for stem in FIGURE_SIZES_IN:
        assert mpimg.imread(out / f"{stem}.png").ndim == 3
    assert "paper-circle" in proc.stdout and "metrics.json" in proc.stdout


def test_metrics_json_agrees_with_the_saved_run(circle_run):
    """metrics.json is compute_metrics of the stored time series (an independent re-read)."""
    _, out = circle_run
    metrics = read_metrics(out / "metrics.json")
    run = load_run(out / "run.npz")
    for key, value in compute_metrics(run, settle_time_s=1.0).items():
        expected = pytest.approx(value, rel=1e-12) if isinstance(value, float) else value
        assert metrics[key] == expected, key


def test_paper_circle_tracks_the_reference(circle_run):
    """The paper's claim for paper-circle, loosely: millimetre tracking after the start, theta stays near 0."""
    _, out = circle_run
    metrics = read_metrics(out / "metrics.json")
    assert metrics["max_position_error_m"] < 0.01
    assert metrics["max_abs_theta_error_rad"] < 0.01
    assert metrics["voltage_within_supply"] is True


def test_default_out_dir_is_out_scenario(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "--scenario", "point-to-point", "--duration", "0.2", "--no-progress", "--no-plots"]) == 0
    assert read_metrics(tmp_path / "out" / "point-to-point" / "metrics.json")["scenario"] == "point-to-point"


def test_robustness_runs_the_registrys_mismatch_and_noise(tmp_path, capsys):
    out = tmp_path / "rob"
    assert main(["simulate", "--scenario", "robustness", "--duration", "0.5", "--out", str(out), "--no-progress",
                 "--no-plots"]) == 0
    run = load_run(out / "run.npz")
    assert run.scenario == "robustness" and run.meta["odometry_noise"] == [1e-3, 1e-3]
    assert run.meta["controller_mismatch"] == {"mass": 1.2, "inertia": 0.8, "friction": 2.0}


@pytest.mark.parametrize("name, hint", [("square", "(valid: paper-circle"),
                                        ("robustnes", "did you mean 'robustness'")])
def test_unknown_scenario_exits_2_without_traceback(tmp_path, name, hint):
    proc = _cli("simulate", "--scenario", name, "--out", str(tmp_path / "x"), "--no-progress")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]  # after argparse's usage
    assert last.startswith("robotino-geom-mpc simulate: error: argument --scenario:") and name in last and hint in last
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--scenario", "paper-circle", "--duration", "-1"], "--duration"),
        (["--scenario", "paper-circle", "--duration", "0"], "--duration"),
        (["--scenario", "paper-circle", "--duration", "nan"], "--duration"),
        (["--scenario", "paper-circle", "--duration", "inf"], "--duration"),
        (["--scenario", "paper-circle", "--duration", "abc"], "--duration"),
        (["--scenario", "paper-circle", "--seed", "-3"], "--seed"),
        (["--scenario", "paper-circle", "--odometry", "lidar"], "--odometry"),
        ([], "--scenario"),
    ],
)
def test_bad_options_exit_2(capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_missing_params_file_exits_2(tmp_path, capsys):
    missing = tmp_path / "nope.yaml"
    status = main(["simulate", "--scenario", "paper-circle", "--params", str(missing), "--out", str(tmp_path / "o")])
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.yaml" in err[0]


def test_encoder_odometry_reports_both_frames(tmp_path):
    out = tmp_path / "enc"
    proc = _cli("simulate", "--scenario", "paper-circle", "--duration", "3", "--odometry", "encoders", "--out",
                str(out), "--no-progress", "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert not list(out.glob("*.png")) and "and 0 figures" in proc.stdout  # --no-plots
    metrics, run = read_metrics(out / "metrics.json"), load_run(out / "run.npz")
    assert run.meta["odometry"] == "encoders"
    assert metrics == pytest.approx({**compute_metrics(run, settle_time_s=1.0), **{
        k: metrics[k] for k in ("wall_time_s", "realtime_factor")}})
    assert 0.0 < metrics["odometry_drift_max_m"] < 1e-3
    assert metrics["rms_position_error_odom_m"] != metrics["rms_position_error_m"]
    assert "in the odom frame (encoders)" in proc.stdout


@pytest.mark.parametrize("args, option", [
    (["--link-loss", "1"], "--link-loss"),
    (["--link-loss", "0.6"], "--link-loss"),  # isolated losses (bursts of 1) cannot make 60 %
    (["--link-delay-ms", "-5"], "--link-delay-ms"),
    (["--link-jitter-ms", "20000"], "--link-jitter-ms"),
    (["--link-burst", "0.5", "--link-loss", "0.1"], "--link-burst"),
])
def test_link_options_out_of_range_exit_2_naming_the_option(tmp_path, capsys, args, option):
    status = main(["simulate", "--scenario", "paper-circle", "--duration", "0.1", "--no-progress",
                   "--out", str(tmp_path / "o"), *args])
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0] and "Traceback" not in err[0]  # the unit typed: test_cli_options


def test_a_run_over_a_link_reports_it(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["simulate", "--scenario", "paper-circle", "--duration", "0.5", "--no-progress", "--no-plots", "--out",
                 str(out), "--link-delay-ms", "20", "--link-loss", "0.2", "--link-burst", "2"]) == 0
    text = capsys.readouterr().out
    assert "link: up " in text and "compensated: round trip" in text
    assert main(["simulate", "--scenario", "paper-circle", "--duration", "0.5", "--no-progress", "--no-plots", "--out",
                 str(out), "--link-delay-ms", "20", "--no-compensation"]) == 0
    assert "uncompensated" in capsys.readouterr().out
