"""The DDS benchmark's measurements are well-formed: the plant's reports of its lockstep and realtime runs."""

import math

from robotino_geom_mpc.core.params import load_params
from robotino_geom_mpc.nodes.dds_bench import bench_lockstep, bench_realtime


def test_lockstep_figure_is_the_plants_report_of_every_tick():
    _, control = load_params()
    out = bench_lockstep(duration_s=2.0, timeout_s=120.0)
    assert out["ticks"] == round(2.0 / control.period_s)
    assert math.isfinite(out["lockstep_dds_realtime_factor"]) and out["lockstep_dds_realtime_factor"] > 0.0


def test_realtime_figures_are_the_plants_count_of_answered_ticks():
    _, control = load_params()
    out = bench_realtime(duration_s=6.0)
    assert out["realtime_expected_ticks"] == round(6.0 / control.period_s)
    # the plant's clock starts before discovery completes (which can take a Fast DDS announcement period of
    # 3 s); the count starts at the first answered tick and never exceeds the run
    assert 100 <= out["realtime_ticks"] <= out["realtime_expected_ticks"]
    assert 0 <= out["realtime_missed_ticks"] < out["realtime_ticks"]  # ticks are answered
    # answers follow their odometry, within a control period at the median
    assert 0.0 < out["realtime_latency_median_ms"] <= out["realtime_latency_p99_ms"] <= out["realtime_latency_max_ms"]
    assert out["realtime_latency_median_ms"] < 1e3 * control.period_s
