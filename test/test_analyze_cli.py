"""`robotino-geom-mpc analyze`: JSON output for both presets, text report, bad files."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]


def _run(*args):
    return subprocess.run(
        [sys.executable, "-m", "robotino_geom_mpc", "analyze", *args],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )


@pytest.fixture(scope="module", params=("config/robotino3.yaml", "config/robotino2.yaml"))
def analysis(request):
    result = _run("--params", request.param, "--json")
    assert result.returncode == 0, result.stderr
    return request.param, json.loads(result.stdout)


def test_json_has_the_computed_orders_and_residuals(analysis):
    path, report = analysis
    assert report["params_file"] == path
    assert report["functional_controllability_order"] == {"mechanical": 2, "drive": 1, "cascade": 3}
    assert report["decoupling_max_residual"] <= 1e-9
    assert report["theta_grid_points"] >= 3600
    assert report["singular_points_included"] is True
    assert report["decoupling_passed"] is True
    assert {c["equation"] for c in report["conditions"]} == {f"({k})" for k in range(12, 22)}


def test_json_decoupling_field_inverts_the_model(analysis):
    from robotino_geom_mpc.model.dynamics import acceleration_block

    path, report = analysis
    robot = load_params(REPO / path)[0]
    assert np.allclose(np.array(report["T0"]) @ acceleration_block(0.0, robot), np.eye(3), atol=1e-12)


def test_errata_figures(analysis):
    path, report = analysis
    robot, control = load_params(REPO / path)
    errata = {e["id"]: e for e in report["errata"]}
    assert sorted(errata) == [1, 2, 3, 4, 5, 6]
    # 1: the printed angular row (l/J, l sin(5pi/6 + 2 theta)/J, -l/J) makes the block singular at the root
    M, J, l = robot.M, robot.J, robot.l

    def printed_det(th):
        phi = np.array([0.0, 2 * np.pi / 3, -2 * np.pi / 3]) + th
        rows = np.vstack((np.sin(phi) / M, np.cos(phi) / M, [l / J, l * np.sin(5 * np.pi / 6 + 2 * th) / J, -l / J]))
        return np.linalg.det(rows)

    root = errata[1]["printed_det_zero_nearest_0_rad"]
    assert 0.1 < root < 0.3
    assert printed_det(root - 1e-3) * printed_det(root + 1e-3) < 0
    assert errata[1]["corrected_det_max"] - errata[1]["corrected_det_min"] < 1e-12 * abs(errata[1]["corrected_det_min"])
    # 3: the step-by-step simulation agrees with the corrected F_2p, not with the printed one
    assert errata[3]["corrected_rel_error"] < 1e-12 < 1e-3 < errata[3]["printed_rel_error"]
    assert len(errata[3]["f2p_simulated"]) == control.horizon
    # 4: the gear multiplies the force per ampere
    assert errata[4]["force_per_ampere_n"] == pytest.approx(robot.gear_ratio * errata[4]["force_per_ampere_paper_n"])
    # 6: with the printed rows the body-frame acceleration of fixed forces turns by -2 theta, a rigid body's by 0;
    # a rotation command accelerates the yaw counter-clockwise, through equal positive wheel forces
    theta = errata[6]["theta_rad"]
    assert errata[6]["body_acceleration_turn_printed_rad"] == pytest.approx(-2.0 * theta, abs=1e-12)
    assert abs(errata[6]["body_acceleration_turn_corrected_rad"]) < 1e-12
    np.testing.assert_allclose(errata[6]["rotation_command_acceleration"], [0.0, 0.0, 1.0], atol=1e-12)
    forces = np.array(errata[6]["rotation_pattern_forces_n"])
    assert np.all(forces > 0.0) and np.ptp(forces) < 1e-12 * forces.max()


def test_text_report(capsys):
    status = main(["analyze", "--n-theta", "90"])
    out = capsys.readouterr().out
    assert status == 0
    assert "robotino3.yaml" in out
    assert "orders: mechanical 2, drive 1, cascade 3" in out
    assert "pi/2 + k pi included: yes" in out
    assert "decoupling checks: all passed" in out


def test_bad_parameter_file_exits_2_with_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**:\n  ros__parameters: [1, 2]\n")
    result = _run("--params", str(bad), "--json")
    assert result.returncode == 2
    assert result.stdout == ""
    assert len(result.stderr.strip().splitlines()) == 1 and "bad.yaml" in result.stderr
    assert "Traceback" not in result.stderr


def test_bad_grid_size_is_a_usage_error(capsys):
    assert main(["analyze", "--n-theta", "1"]) == 2
    assert "--n-theta" in capsys.readouterr().err
