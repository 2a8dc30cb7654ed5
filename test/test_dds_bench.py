"""The DDS benchmark's measurements are well-formed: the plant's tick count, and realtime ticks and latencies."""

import math

from robotino_geom_mpc.core.params import load_params
from robotino_geom_mpc.nodes.dds_bench import bench_lockstep, bench_realtime


def test_lockstep_figure_is_the_plants_report_of_every_tick():
    _, control = load_params()
    out = bench_lockstep(duration_s=2.0, timeout_s=120.0)
    assert out["ticks"] == round(2.0 / control.period_s)
    assert math.isfinite(out["lockstep_dds_realtime_factor"]) and out["lockstep_dds_realtime_factor"] > 0.0


def test_realtime_probe_sees_the_ticks_and_their_answers():
    _, control = load_params()
    out = bench_realtime(duration_s=4.0)
    assert out["realtime_expected_ticks"] == round(4.0 / control.period_s)
    # the plant's clock starts before discovery completes (which can take a Fast DDS announcement period of
    # 3 s): from then on the probe sees every tick, one per period of the odometry's DDS source times (a
    # publish timer delayed past a whole period skips it, as rcl timers do)
    assert out["realtime_probe_span_s"] >= 0.5
    span_ticks = out["realtime_probe_span_s"] / control.period_s + 1
    assert 0.95 * span_ticks - 2 <= out["realtime_ticks"] <= span_ticks + 2
    assert out["realtime_ticks"] <= out["realtime_expected_ticks"] + 1
    assert 0 <= out["realtime_missed_ticks"] < out["realtime_ticks"]  # ticks are answered
    assert 0.0 < out["realtime_latency_median_ms"] <= out["realtime_latency_p99_ms"]  # answers follow their odometry
