"""`robotino-geom-mpc run`: nodes as processes, recorded, metrics from the recording equal `simulate`'s."""

import json
import math
import os
import subprocess
import sys
import time

import pytest
import yaml

from robotino_geom_mpc.system.processes import node_arguments, wait_for_exit
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.recording.regress import regress_bag

pytestmark = pytest.mark.ros

DURATION_S = 3.0  # `paper_circle_run`'s (conftest)


def _cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "robotino_geom_mpc", *args], capture_output=True, text=True,
                          timeout=timeout, env=os.environ.copy())


def _no_node_left(out_dir):
    """No process of this run is left: none has the run's folder on its command line."""
    ps = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout
    return str(out_dir) not in ps


def test_run_lockstep_records_and_reports_the_metrics_of_simulate(paper_circle_run):
    out, proc, duration_s = paper_circle_run
    assert duration_s == DURATION_S
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert _no_node_left(out)
    assert sorted(p.name for p in out.glob("*.png"))  # the same figures as simulate
    _assert_metrics_of_simulate(out, "paper-circle")
    for name in ("plant_node", "controller_node", "trajectory_node", "recorder_node"):
        assert "Traceback" not in (out / "logs" / f"{name}.err.log").read_text()


def test_run_robustness_is_simulates_robustness_with_its_mismatch_and_noise(tmp_path):
    """The nodes get the scenario's controller model and odometry noise: the recording's metrics are those of the
    offline robustness run with the same seed (the nominal loop tracks to microns, this one to a tenth of a mm).
    """
    out = tmp_path / "robustness"
    proc = _cli("run", "--scenario", "robustness", "--duration", "2", "--seed", "4", "--out", str(out), "--no-plots")
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert not list(out.glob("*.png"))  # --no-plots: the metrics only
    metrics = _assert_metrics_of_simulate(out, "robustness", duration_s=2.0, seed=4)
    assert metrics["rms_position_error_m"] > 2e-5
    result = regress_bag(out / "bag")  # the replay builds the controller the run had: the mismatched model
    assert result.passed and result.compared == result.ticks == 200, result


def _assert_metrics_of_simulate(out, scenario, duration_s=DURATION_S, seed=0) -> dict:
    """DIR/metrics.json of `run` equals compute_metrics of `run_scenario` (wall-clock times aside)."""
    metrics = json.loads((out / "metrics.json").read_text())
    robot, control = load_params()
    want = compute_metrics(run_scenario(RunConfig(scenario, robot, control, duration_s=duration_s, seed=seed)))
    for key, value in want.items():
        if key.startswith("compute_time"):
            continue  # wall-clock measurements
        if isinstance(value, float) and math.isfinite(value):
            assert metrics[key] == pytest.approx(value, rel=1e-6, abs=1e-12), key
        else:
            assert metrics[key] == value, key
    return metrics


def test_a_failing_node_is_named_and_nothing_is_left_running(tmp_path):
    params = yaml.safe_load(default_params_file().read_text())
    params["robotino_controller"] = {"ros__parameters": {"mode": "turbo"}}  # only the controller refuses
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(params))
    out = tmp_path / "failed"
    proc = _cli("run", "--scenario", "paper-circle", "--duration", "1", "--out", str(out), "--params", str(bad),
                "--no-record", timeout=120)
    assert proc.returncode == 1
    assert "controller_node exited with status 2" in proc.stderr and "mode" in proc.stderr
    assert _no_node_left(out)


def test_wait_for_exit_wakes_at_an_exit_and_else_at_its_timeout():
    """`wait_for_exit` (the run's waits for its nodes) returns when one of the processes ends, not at the end of
    its 60 s timeout (woken, not timed out: well under half of it), and with none ending after its timeout.
    """
    quick = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.3)"])
    slow = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        start = time.monotonic()
        wait_for_exit([slow, quick], 60.0)
        woken_after = time.monotonic() - start
        assert quick.poll() == 0 and slow.poll() is None and woken_after < 30.0
        start = time.monotonic()
        wait_for_exit([slow, quick], 0.2)  # the quick one is reaped: only the slow one is waited for
        assert slow.poll() is None and time.monotonic() - start >= 0.2
    finally:
        slow.kill()
        slow.wait()
        quick.wait()


def test_each_node_gets_its_scenarios_overrides():
    """node_arguments passes node_parameters on: robustness reaches the controller and the plant, not only the
    trajectory (values against the file's robot, scaled by hand).
    """
    robot, _ = load_params()
    args = node_arguments("robustness", default_params_file(), 3.0, True, seed=5)
    assert args["controller_node"][-4:] == ["-p", "mode:=lockstep", "-p", "lockstep_command_readers:=1"]
    controller = " ".join(args["controller_node"])
    assert f"robot.mass_kg:={1.2 * robot.mass_kg!r}" in controller
    assert f"robot.yaw_inertia_kg_m2:={0.8 * robot.yaw_inertia_kg_m2!r}" in controller
    assert f"robot.body_friction_theta_n_m_s:={2.0 * robot.body_friction_theta_n_m_s!r}" in controller
    plant = " ".join(args["plant_node"])
    assert "odometry_noise.position_m:=0.001" in plant and "odometry_noise.yaw_rad:=0.001" in plant
    assert "seed:=5" in plant and "duration_s:=3.0" in plant
    assert "scenario:=robustness" in " ".join(args["trajectory_node"])
    assert "robot." not in " ".join(node_arguments("paper-circle", default_params_file(), 3.0, True)["controller_node"])


@pytest.mark.parametrize("scenario, bag, port, interface, readers", [
    ("paper-circle", None, None, "voltages", 1), ("paper-circle", "b", None, "voltages", 2),
    ("paper-circle", "b", 8765, "voltages", 3), ("paper-circle", "b", None, "cmd_vel", 2),
    ("wifi", None, None, "voltages", 1), ("wifi", "b", None, "voltages", 2), ("wifi", "b", None, "cmd_vel", 2)])
def test_a_lockstep_controller_holds_its_answer_for_the_command_readers_the_plant_waits_for(scenario, bag, port,
                                                                                            interface, readers):
    """The plant's reader, the recorder's, the live view's: the plant waits for them on the topic of its answers
    (the command's; over a link the plans') before tick 0, and the controller's writer must have matched them
    before its first answer (realtime: no such wait).
    """
    topic = "wheel_voltages" if interface == "voltages" else "cmd_vel"
    if scenario == "wifi":
        topic = {"voltages": "wheel_voltage_plan", "cmd_vel": "cmd_vel_plan"}[interface]
    args = node_arguments(scenario, default_params_file(), 3.0, True, bag=bag, live_view_port=port,
                          command_interface=interface)
    assert f"lockstep_command_readers:={readers}" in args["controller_node"]
    wait_for = " ".join(args["plant_node"])
    assert (f'"{topic}:{readers}"' in wait_for) if bag else (topic not in wait_for)  # without: the plant's own
    realtime = node_arguments(scenario, default_params_file(), 3.0, False, bag=bag, command_interface=interface)
    assert not any("lockstep_command_readers" in arg for arg in realtime["controller_node"])


def test_unknown_scenario_is_a_usage_error(tmp_path):
    proc = _cli("run", "--scenario", "spiral", "--out", str(tmp_path / "x"), timeout=60)
    assert proc.returncode == 2 and "spiral" in proc.stderr
