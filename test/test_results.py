"""RunData validation, metrics against hand-computable runs, metrics.json and .npz round trips."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from robotino_geom_mpc.offline.results import (
    METRIC_KEYS,
    MetricsError,
    RunData,
    RunDataError,
    compute_metrics,
    load_run,
    read_metrics,
    save_run,
    write_metrics,
)

pytestmark = pytest.mark.unit

TS = 0.01


def make_run(n: int = 301, **overrides) -> RunData:
    """A run on a circle with zero error, currents 0.5 A, voltages 6 V; fields overridable."""
    t = np.arange(n) * TS
    reference = np.c_[0.5 * np.cos(t), 0.5 * np.sin(t), 0.1 * t]
    fields = dict(
        scenario="synthetic",
        t=t,
        pose=reference.copy(),
        reference=reference,
        currents=np.full((n, 3), 0.5),
        voltages=np.full((n, 3), 6.0),
        control_period_s=TS,
        horizon=4,
        nominal_current_a=0.86,
        supply_voltage_v=24.0,
    )
    fields.update(overrides)
    return RunData(**fields)


def test_constant_offset_after_settle_gives_rms_equal_max():
    run = make_run()
    pose = run.reference.copy()
    before = run.t < 1.0
    pose[before, 0] += 0.3  # large start transient, excluded by the settle time
    pose[~before, 0] += 1e-3
    m = compute_metrics(make_run(pose=pose), settle_time_s=1.0)
    assert m["rms_position_error_m"] == pytest.approx(1e-3, rel=1e-9)
    assert m["max_position_error_m"] == pytest.approx(1e-3, rel=1e-9)
    assert m["rms_x_error_m"] == pytest.approx(1e-3, rel=1e-9)
    assert m["rms_y_error_m"] == pytest.approx(0.0, abs=1e-15)
    assert m["samples_after_settle"] == int(np.sum(~before))
    assert m["duration_s"] == pytest.approx(3.0)
    assert m["settle_time_s"] == 1.0


def test_position_error_is_euclidean_and_per_axis_rms():
    run = make_run()
    m = compute_metrics(make_run(pose=run.reference + [3e-3, -4e-3, 0.0]))
    assert m["rms_position_error_m"] == pytest.approx(5e-3, rel=1e-9)  # 3-4-5 triangle
    assert m["max_position_error_m"] == pytest.approx(5e-3, rel=1e-9)
    assert m["rms_x_error_m"] == pytest.approx(3e-3, rel=1e-9)
    assert m["rms_y_error_m"] == pytest.approx(4e-3, rel=1e-9)
    assert m["final_position_error_m"] == pytest.approx(5e-3, rel=1e-9)


def test_sinusoidal_error_rms_is_amplitude_over_sqrt2():
    # after the settle time, exactly 4 periods of 48 samples each (the peak is a sample)
    n = 100 + 4 * 48
    run = make_run(n=n)
    amplitude = 2e-3
    phase = 2.0 * np.pi * (np.arange(n) - 100) / 48.0
    pose = run.reference.copy()
    pose[:, 1] += amplitude * np.sin(phase)
    m = compute_metrics(make_run(n=n, pose=pose), settle_time_s=1.0)
    assert m["rms_position_error_m"] == pytest.approx(amplitude / math.sqrt(2.0), rel=1e-9)
    assert m["max_position_error_m"] == pytest.approx(amplitude, rel=1e-9)


def test_current_spike_at_start_counts_in_peak_only_before_settle():
    run = make_run()
    currents = run.currents.copy()
    currents[0, 1] = -2.0  # start transient, negative: the peak is an absolute value
    m = compute_metrics(make_run(currents=currents))
    assert m["peak_current_a"] == 2.0
    assert m["peak_current_after_settle_a"] == 0.5
    assert m["samples_above_nominal_current"] == 1
    assert m["current_within_nominal"] is False
    assert compute_metrics(run)["current_within_nominal"] is True


def test_peak_voltage_is_absolute_over_whole_run():
    run = make_run()
    voltages = run.voltages.copy()
    voltages[0, 2] = -23.5
    m = compute_metrics(make_run(voltages=voltages))
    assert m["peak_voltage_v"] == 23.5
    assert m["voltage_within_supply"] is True
    voltages[5, 0] = 30.0
    assert compute_metrics(make_run(voltages=voltages))["voltage_within_supply"] is False


def test_theta_error_is_wrapped_and_counts_from_the_start():
    run = make_run()
    reference = run.reference.copy()
    pose = run.reference.copy()
    reference[:, 2] = -np.pi + 0.01
    pose[:, 2] = np.pi - 0.01  # error -0.02 rad across the +-pi cut
    pose[0, 2] -= 0.03  # error -0.02 - 0.03 at t = 0, before the settle time: still counted
    m = compute_metrics(make_run(pose=pose, reference=reference))
    assert m["max_abs_theta_error_rad"] == pytest.approx(0.05, abs=1e-12)
    assert m["rms_theta_error_rad"] == pytest.approx(0.02, abs=1e-12)
    # whole turns are no error
    m2 = compute_metrics(make_run(pose=run.reference + [0.0, 0.0, 4.0 * np.pi]))
    assert m2["max_abs_theta_error_rad"] == pytest.approx(0.0, abs=1e-12)


def test_run_shorter_than_settle_time_has_no_position_metrics():
    m = compute_metrics(make_run(n=50), settle_time_s=1.0)
    assert m["samples_after_settle"] == 0
    assert m["rms_position_error_m"] is None and m["max_position_error_m"] is None
    assert m["peak_current_a"] == 0.5


def test_metrics_carry_the_run_scalars_flags_and_compute_times():
    n = 301
    flags = {"saturated": np.arange(n) % 100 == 0, "infeasible": np.zeros(n, dtype=bool)}
    compute = np.linspace(1e-5, 3e-5, n)  # median of an odd linspace is its middle value
    m = compute_metrics(make_run(flags=flags, compute_time_s=compute))
    assert list(m)[: len(METRIC_KEYS)] == list(METRIC_KEYS)
    assert (m["control_period_s"], m["horizon"], m["nominal_current_a"], m["supply_voltage_v"]) == (TS, 4, 0.86, 24.0)
    assert m["saturated_steps"] == 4 and m["infeasible_steps"] == 0
    assert m["compute_time_median_s"] == pytest.approx(2e-5)
    assert m["compute_time_max_s"] == pytest.approx(3e-5)


def test_negative_settle_time_rejected():
    with pytest.raises(RunDataError, match="settle_time_s"):
        compute_metrics(make_run(), settle_time_s=-1.0)


@pytest.mark.parametrize(
    "overrides, match",
    [
        (dict(pose=np.zeros((300, 3))), "pose"),
        (dict(reference=np.zeros((301, 2))), "reference"),
        (dict(currents=np.full((301, 3), np.nan)), "currents"),
        (dict(voltages=np.full((301, 3), np.inf)), "voltages"),
        (dict(t=np.zeros(301)), "increasing"),
        (dict(control_period_s=-0.01), "control_period_s"),
        (dict(control_period_s=float("nan")), "control_period_s"),
        (dict(horizon=0), "horizon"),
        (dict(horizon=True), "horizon"),
        (dict(horizon=2.5), "horizon"),
        (dict(nominal_current_a=0.0), "nominal_current_a"),
        (dict(supply_voltage_v="24"), "supply_voltage_v"),
        (dict(scenario=""), "scenario"),
        (dict(flags={"saturated": np.zeros(5, dtype=bool)}), "saturated"),
        (dict(compute_time_s=np.zeros(3)), "compute_time_s"),
    ],
)
def test_invalid_run_rejected(overrides, match):
    with pytest.raises(RunDataError, match=match):
        make_run(**overrides)


def test_metrics_json_round_trip_with_sorted_keys(tmp_path):
    m = compute_metrics(make_run(flags={"saturated": np.ones(301, dtype=bool)}))
    path = write_metrics(m, tmp_path / "sub" / "metrics.json")
    text = path.read_text()
    keys = list(json.loads(text, object_pairs_hook=lambda pairs: [k for k, _ in pairs]))
    assert keys == sorted(keys)
    assert read_metrics(path) == m
    # stable: writing the same metrics again gives the same bytes
    assert write_metrics(dict(reversed(list(m.items()))), tmp_path / "again.json").read_text() == text


def test_numpy_scalars_written_as_plain_json(tmp_path):
    path = write_metrics({"a": np.float64(1.5), "b": np.int64(3), "c": np.bool_(True)}, tmp_path / "m.json")
    assert json.loads(path.read_text()) == {"a": 1.5, "b": 3, "c": True}


def test_non_finite_metric_rejected(tmp_path):
    with pytest.raises(MetricsError, match="JSON"):
        write_metrics({"rms_position_error_m": float("nan")}, tmp_path / "m.json")


@pytest.mark.parametrize("content", ["{not json", "[1, 2]"])
def test_corrupt_metrics_file_rejected(tmp_path, content):
    path = tmp_path / "metrics.json"
    path.write_text(content)
    with pytest.raises(MetricsError, match="metrics.json"):
        read_metrics(path)
    with pytest.raises(MetricsError, match="cannot read"):
        read_metrics(tmp_path / "missing.json")


def test_run_npz_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    run = make_run(
        pose=make_run().reference + rng.normal(0, 1e-3, (301, 3)),
        currents=rng.normal(0, 0.4, (301, 3)),
        flags={"saturated": rng.random(301) < 0.1},
        compute_time_s=rng.random(301) * 1e-4,
        meta={"seed": 7, "params": "robotino3.yaml"},
        odometry=make_run().reference + rng.normal(0, 1e-3, (301, 3)),
    )
    back = load_run(save_run(run, tmp_path / "run.npz"))
    for name in ("t", "pose", "reference", "currents", "voltages", "compute_time_s", "odometry"):
        np.testing.assert_array_equal(getattr(back, name), getattr(run, name))
    np.testing.assert_array_equal(back.flags["saturated"], run.flags["saturated"])
    assert (back.scenario, back.horizon, back.meta) == (run.scenario, run.horizon, run.meta)
    assert compute_metrics(back) == compute_metrics(run)


def test_corrupt_run_file_rejected(tmp_path):
    path = tmp_path / "run.npz"
    path.write_bytes(b"not a zip file")
    with pytest.raises(RunDataError, match="run.npz"):
        load_run(path)
    np.savez(path, t=np.arange(3.0))
    with pytest.raises(RunDataError, match="missing"):
        load_run(path)


def test_odometry_frame_metrics_beside_the_ground_truth_ones():
    run = make_run()
    truth, odometry = run.reference.copy(), run.reference.copy()
    truth[:, 1] += 2e-3  # the true robot 2 mm off in y
    odometry[:, 0] += 3e-4  # the controller believes itself 0.3 mm off in x
    odometry[:, 2] += 1e-3
    odometry[-1, 1] += 4e-3
    m = compute_metrics(make_run(pose=truth, odometry=odometry), settle_time_s=1.0)
    assert m["rms_position_error_m"] == pytest.approx(2e-3, rel=1e-9)  # unchanged meaning: the truth
    after = int(np.sum(run.t >= 1.0 - 1e-12))
    assert m["rms_position_error_odom_m"] == pytest.approx(
        math.sqrt(((after - 1) * 3e-4**2 + (3e-4**2 + 4e-3**2)) / after), rel=1e-9)
    assert m["max_position_error_odom_m"] == pytest.approx(math.hypot(3e-4, 4e-3), rel=1e-9)
    assert m["rms_theta_error_odom_rad"] == pytest.approx(1e-3, rel=1e-9)
    assert m["odometry_drift_final_m"] == pytest.approx(math.hypot(3e-4, 2e-3), rel=1e-9)
    assert m["odometry_drift_max_m"] == pytest.approx(math.hypot(3e-4, 2e-3), rel=1e-9)
    assert "rms_position_error_odom_m" not in compute_metrics(run)  # no odometry recorded: no such keys
    with pytest.raises(RunDataError, match="odometry"):
        make_run(odometry=np.zeros((5, 3)))
