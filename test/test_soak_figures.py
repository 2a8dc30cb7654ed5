"""The soak's verdicts (`bench.soak`) against truths known by construction.

* Memory growth: `growth_mb_per_10min` of RSS samples on a line is its slope, in MB per 10 minutes.
* Latency drift: `latency_drift` on windows with a steady trend of two noise widths per window finds it; on
  windows drawn independently from one distribution (no drift) it finds drift in about `DRIFT_ALPHA` of the
  cases, as a test of that level must; its p-value is the exact fraction of orderings, checked by enumeration.
"""

import itertools

import numpy as np
import pytest

from robotino_geom_mpc.bench.soak import DRIFT_ALPHA, growth_mb_per_10min, latency_drift, soak_table

pytestmark = pytest.mark.unit


def test_growth_is_the_slope_of_the_samples_in_mb_per_10_minutes():
    times = [0.0, 100.0, 200.0, 300.0]
    assert growth_mb_per_10min(times, [80.0 + 0.002 * t for t in times]) == pytest.approx(1.2)
    # least squares: sum (t - 150)(v - 80) = -50 MB s over sum (t - 150)^2 = 50000 s^2: -0.001 MB/s
    assert growth_mb_per_10min(times, [80.0, 80.5, 79.5, 80.0]) == pytest.approx(-0.6)
    assert np.isnan(growth_mb_per_10min([0.0], [80.0]))


def test_a_steady_trend_of_two_noise_widths_per_window_is_a_drift():
    rng = np.random.default_rng(7)
    found = [latency_drift(list(2.0 * np.arange(6) + rng.normal(size=6)))["drift"] for _ in range(200)]
    assert np.mean(found) > 0.8
    steady = latency_drift([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])  # a pure trend: the change is 5 steps, the most
    assert steady["drift"] and steady["ratio"] == pytest.approx(5.0) and steady["p"] == pytest.approx(2 / 720)
    assert steady["change"] == 5.0 and steady["step"] == 1.0


def test_windows_without_drift_are_called_drifting_at_the_test_level():
    rng = np.random.default_rng(11)
    found = [latency_drift(list(3.0 + 0.5 * rng.standard_normal(6)))["drift"] for _ in range(1000)]
    assert np.mean(found) <= 2.5 * DRIFT_ALPHA  # 1000 draws: 10 expected, 25 is far beyond their noise


def test_the_p_value_is_the_fraction_of_orderings_at_least_as_extreme():
    values = [2.1, 2.6, 2.4, 3.0, 2.2]

    def ratio(v):
        steps = np.diff(v)
        return abs(v[-1] - v[0]) / np.sqrt(np.mean(steps ** 2))

    orders = list(itertools.permutations(values))
    expected = sum(ratio(np.array(o)) >= ratio(np.array(values)) - 1e-12 for o in orders) / len(orders)
    result = latency_drift(values)
    assert result["ratio"] == pytest.approx(ratio(np.array(values)))
    assert result["p"] == pytest.approx(expected)
    assert latency_drift([1.0, 2.0])["drift"] is None


def test_more_than_eight_windows_draw_orderings_and_still_find_a_trend():
    rng = np.random.default_rng(3)
    drifting = latency_drift(list(np.arange(12) + 0.3 * rng.normal(size=12)))
    flat = latency_drift(list(rng.normal(size=12)))
    assert drifting["drift"] and drifting["p"] < 1e-3
    assert 0.0 < flat["p"] <= 1.0


def test_the_table_prints_the_verdicts_with_their_numbers():
    windows = [{"start_s": 100.0 * k, "end_s": 100.0 * (k + 1), "ticks": 10000, "missed": 0, "load": 1.0,
                "latency_ms": {"p50": 2.0 + 0.5 * k, "p99": 5.0, "p99.9": 8.0}, "processes": {}} for k in range(6)]
    drift = {q: latency_drift([w["latency_ms"][q] for w in windows]) for q in ("p50", "p99", "p99.9")}
    result = {"windows": windows, "growth": {"recorder_node": 1.5, "plant_node": 0.1}, "drift": drift,
              "ticks": 60000, "bag": {}, "lost": {}, "before": {}}
    text = "\n".join(soak_table(result))
    assert "above 1 for recorder_node" in text
    assert "latency p50: first 2.00 ms, last 4.50 ms, change +2.50 ms" in text and "DRIFT" in text
    assert "latency p99: first 5.00 ms, last 5.00 ms, change +0.00 ms" in text and "no drift" in text
