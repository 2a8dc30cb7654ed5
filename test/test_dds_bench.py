"""The DDS benchmark's measurements are well-formed: the plant's reports of its lockstep and realtime runs."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.core.params import load_params
from robotino_geom_mpc.bench import dds as dds_bench
from robotino_geom_mpc.bench.dds import bench_lockstep, bench_realtime, missed_ticks, realtime_report
from robotino_geom_mpc.bench.host_steal import PROC_STAT
from robotino_sim_node.loop_timing import MISSES_KEPT, LoopTiming


def test_lockstep_figure_is_the_plants_report_of_every_tick():
    _, control = load_params()
    out = bench_lockstep(duration_s=2.0, timeout_s=120.0)
    assert out["ticks"] == round(2.0 / control.period_s)
    assert math.isfinite(out["lockstep_dds_realtime_factor"]) and out["lockstep_dds_realtime_factor"] > 0.0
    assert out["host_steal_ms"] >= 0.0 if PROC_STAT.exists() else "host_steal_ms" not in out


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
    if PROC_STAT.exists():  # the host's steal over the run, and the misses during it
        assert out["realtime_host_steal_ms"] >= 0.0
        assert 0 <= out["realtime_missed_ticks_in_host_steal"] <= out["realtime_missed_ticks"]


@settings(max_examples=50, deadline=None)
@given(st.lists(st.booleans(), min_size=2, max_size=150), st.floats(min_value=0.0, max_value=3e4))
def test_the_missed_ticks_read_back_from_the_plants_report(answers, start):
    """`missed_ticks` and `realtime_report` read what `LoopTiming` kept back out of its summary line."""
    timing = LoopTiming()
    for k, answered in enumerate(answers):
        timing.published(start + 0.01 * k)
        if answered:
            timing.command(start + 0.01 * k + 0.002)
    report = f"[INFO] [1795354378.6] [robotino_plant]: realtime run over: {timing.summary()}\n[INFO] other line"
    read = missed_ticks(report)
    assert len(read) == min(timing.missed, MISSES_KEPT) == len(timing.missed_at)
    for (t, gap), (t_kept, gap_kept) in zip(read, timing.missed_at):
        assert t == pytest.approx(t_kept, abs=2e-6) and gap == pytest.approx(gap_kept, abs=1e-6)
    summary = realtime_report(report)
    if not timing.answered:
        assert summary is None  # no latency to report (nan): not a finished run
        return
    assert (summary["answered"], summary["missed"]) == (timing.answered, timing.missed)
    assert summary["first_answer_s"] == pytest.approx(timing.first_answer_at, abs=1e-6)
    assert summary["p99_ms"] == pytest.approx(1e3 * timing.percentile_s(99), abs=1e-3)
    assert summary["max_ms"] == pytest.approx(1e3 * timing.max_latency_s, abs=1e-3)


def test_a_report_without_misses_lists_none():
    assert missed_ticks("realtime run over: 5 ticks answered, 0 missed; ... first answer at steady time 3.0 s") == []
    assert missed_ticks("no report") == [] and realtime_report("no report") is None


def test_dds_benchmarks_takes_the_median_of_the_lockstep_runs_and_passes_the_realtime_figures(monkeypatch):
    """The aggregation alone, with stand-in runs: median, min, max, summed steal, the realtime keys `bench` shows."""
    factors = iter([14.0, 22.0, 9.0])
    steals = iter([10.0, 30.0, 5.0])
    calls = []

    def lockstep(duration_s):
        calls.append(("lockstep", duration_s))
        return {"lockstep_dds_realtime_factor": next(factors), "ticks": 2200, "host_steal_ms": next(steals)}

    def realtime(duration_s):
        calls.append(("realtime", duration_s))
        return {"realtime_missed_ticks": 2, "realtime_ticks": 6000, "realtime_expected_ticks": 6000,
                "realtime_latency_p99_ms": 1.5, "realtime_missed_ticks_in_host_steal": 2}

    monkeypatch.setattr(dds_bench, "bench_lockstep", lockstep)
    monkeypatch.setattr(dds_bench, "bench_realtime", realtime)
    out = dds_bench.dds_benchmarks()
    assert calls == [("lockstep", 22.0)] * dds_bench.LOCKSTEP_RUNS + [("realtime", 60.0)]
    assert out == {"lockstep_dds_realtime_factor": 14.0, "lockstep_dds_realtime_factor_min": 9.0,
                   "lockstep_dds_realtime_factor_max": 22.0, "lockstep_host_steal_ms": 45.0,
                   "realtime_missed_ticks": 2, "realtime_latency_p99_ms": 1.5,
                   "realtime_missed_ticks_in_host_steal": 2}


def test_dds_benchmarks_leaves_out_the_lockstep_steal_when_a_run_could_not_sample_it(monkeypatch):
    runs = iter([{"lockstep_dds_realtime_factor": 12.0, "host_steal_ms": 3.0}, {"lockstep_dds_realtime_factor": 11.0},
                 {"lockstep_dds_realtime_factor": 13.0, "host_steal_ms": 1.0}])
    monkeypatch.setattr(dds_bench, "bench_lockstep", lambda duration_s: next(runs))
    monkeypatch.setattr(dds_bench, "bench_realtime", lambda duration_s: {"realtime_missed_ticks": 0})
    out = dds_bench.dds_benchmarks()
    assert out["lockstep_dds_realtime_factor"] == 12.0 and "lockstep_host_steal_ms" not in out
