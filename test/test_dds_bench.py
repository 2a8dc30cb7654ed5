"""The DDS benchmark: the plant's timing reports read back, the figures and ratios built from them, real runs."""

import json
import subprocess
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.bench import dds as dds_bench
from robotino_geom_mpc.bench.dds import bench_lockstep, bench_realtime, missed_ticks, read_timing_report
from robotino_geom_mpc.bench.registry import BenchmarkError
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.system.processes import NodeProcess
from robotino_sim_node.loop_timing import LoopTiming

pytestmark = pytest.mark.ros

PERIOD_S = load_params()[1].period_s


def lockstep_report(ticks=2200, wall_s=1.1, **changes) -> dict:
    """A lockstep timing report as the plant writes it (the keys of the plant's ``timing_report``)."""
    loop_ticks = ticks - 1
    report = {"mode": "lockstep", "ticks": ticks, "loop_ticks": loop_ticks, "simulated_s": loop_ticks * PERIOD_S,
              "wall_s": wall_s, "realtime_factor": loop_ticks * PERIOD_S / wall_s, "plant_busy_ms_per_tick": 0.08,
              "wait_ms_per_tick": 0.4, "tick0_answer_s": 0.02, "answered": ticks, "missed": 0, "latency_ms": None,
              "first_answer_steady_s": None, "missed_ticks": []}
    return {**report, **changes}


def realtime_report(timing: LoopTiming, **changes) -> dict:
    """The realtime timing report of what `timing` saw (its figures in the plant's JSON keys)."""
    latency = None if not timing.answered else {
        "median": 1e3 * timing.percentile_s(50), "p99": 1e3 * timing.percentile_s(99),
        "max": 1e3 * timing.max_latency_s}
    first = timing.first_answer_at
    report = {"mode": "realtime", "ticks": timing.answered + timing.missed, "loop_ticks": 0, "simulated_s": 6.0,
              "wall_s": 6.0, "realtime_factor": 1.0, "plant_busy_ms_per_tick": 0.05, "wait_ms_per_tick": 0.0,
              "tick0_answer_s": None, "answered": timing.answered, "missed": timing.missed, "latency_ms": latency,
              "first_answer_steady_s": first, "missed_ticks": [[t - first, gap] for t, gap in timing.missed_at]}
    return {**report, **changes}


# reading the report ---------------------------------------------------------------------------------
def test_a_well_formed_report_is_read_as_written(tmp_path):
    path = tmp_path / "timing.json"
    report = lockstep_report()
    path.write_text(json.dumps(report))
    assert read_timing_report(path, "lockstep") == report


@pytest.mark.parametrize("change, named", [
    ({"ticks": 2.5}, "ticks"),
    ({"ticks": True}, "ticks"),  # a bool is not a count
    ({"wall_s": "1.1"}, "wall_s"),
    ({"missed_ticks": None}, "missed_ticks"),
    ({"latency_ms": {"median": 0.4, "p99": 1.0}}, "latency_ms"),
    ({"latency_ms": [0.4, 1.0, 2.0]}, "latency_ms"),
])
def test_a_mistyped_key_is_named(tmp_path, change, named):
    path = tmp_path / "timing.json"
    path.write_text(json.dumps({**lockstep_report(), **change}))
    with pytest.raises(BenchmarkError, match=f"mistypes {named}"):
        read_timing_report(path, "lockstep")


def test_a_missing_key_a_wrong_mode_or_no_file_is_a_benchmark_error(tmp_path):
    path = tmp_path / "timing.json"
    report = lockstep_report()
    del report["first_answer_steady_s"]
    path.write_text(json.dumps(report))
    with pytest.raises(BenchmarkError, match="first_answer_steady_s"):
        read_timing_report(path, "lockstep")
    path.write_text(json.dumps(lockstep_report()))
    with pytest.raises(BenchmarkError, match="of a lockstep run, not realtime"):
        read_timing_report(path, "realtime")
    for text, reason in (("{", "not JSON"), ("[1, 2]", "not a JSON object")):
        path.write_text(text)
        with pytest.raises(BenchmarkError, match=reason):
            read_timing_report(path, "lockstep")
    with pytest.raises(BenchmarkError, match="wrote no timing report"):
        read_timing_report(tmp_path / "missing.json", "lockstep")


@settings(max_examples=50, deadline=None)
@given(st.lists(st.booleans(), min_size=2, max_size=150), st.floats(min_value=0.0, max_value=3e4))
def test_the_missed_ticks_are_placed_on_the_steady_clock(answers, start):
    """`missed_ticks` gives back the steady times `LoopTiming` kept, from the report's times after the first answer."""
    timing = LoopTiming()
    for k, answered in enumerate(answers):
        timing.published(start + 0.01 * k)
        if answered:
            timing.command(start + 0.01 * k + 0.002)
    report = json.loads(json.dumps(realtime_report(timing)))  # through JSON as the plant writes it
    read = missed_ticks(report)
    assert len(read) == len(timing.missed_at)
    for (t, gap), (t_kept, gap_kept) in zip(read, timing.missed_at):
        assert t == pytest.approx(t_kept, abs=1e-9) and gap == pytest.approx(gap_kept, abs=1e-12)


# the figures from a report, with stand-in nodes -----------------------------------------------------------
class StandInSteal:
    """A steal sampler whose host took `stolen` [s] in the window (start, end) and nothing elsewhere."""

    available = True

    def __init__(self, *args, stolen=(5.0, 5.5), **kwargs):
        self.stolen = stolen

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def total_s(self):
        return 0.25

    def during(self, start, end):
        return 0.25 if start < self.stolen[1] and end > self.stolen[0] else 0.0


@pytest.fixture
def stand_in_plant(monkeypatch):
    """`lockstep_nodes` replaced: a process that exits at once after the report given to it is written."""
    written = {}

    def nodes(group, scenario, duration_s, realtime=False, timing_report=None, **_):
        written["mode"] = "realtime" if realtime else "lockstep"
        with open(timing_report, "w") as f:
            json.dump(written["report"], f)
        popen = subprocess.Popen([sys.executable, "-c", "pass"])
        node = NodeProcess("plant_node", popen, group.log_dir / "out", group.log_dir / "err")
        group.nodes.append(node)
        return node

    monkeypatch.setattr(dds_bench, "lockstep_nodes", nodes)
    monkeypatch.setattr(dds_bench, "StealSampler", StandInSteal)
    return written


def test_lockstep_figures_are_the_reports_factor_and_wall_time_per_loop_tick(stand_in_plant):
    stand_in_plant["report"] = lockstep_report(ticks=2201, wall_s=1.6)
    out = bench_lockstep(duration_s=22.01)
    assert out == {"lockstep_dds_realtime_factor": pytest.approx(22.0 / 1.6),
                   "lockstep_tick_us": pytest.approx(1e6 * 1.6 / 2200), "ticks": 2201, "host_steal_ms": 250.0}
    stand_in_plant["report"] = lockstep_report(ticks=1, realtime_factor=None)
    with pytest.raises(BenchmarkError, match="no loop to time"):
        bench_lockstep(duration_s=0.01)


def test_realtime_figures_are_the_reports_counts_and_latencies(stand_in_plant):
    timing = LoopTiming()
    for k in range(600):  # steady time 0 .. 6 s; the ticks at 2.0 s and 5.2 s are missed
        timing.published(0.01 * k)
        if k not in (200, 520):
            timing.command(0.01 * k + 1e-3 * (1 + k % 4))
    stand_in_plant["report"] = realtime_report(timing)
    out = bench_realtime(duration_s=6.0)
    assert out == {"realtime_missed_ticks": 2, "realtime_ticks": 600, "realtime_expected_ticks": round(6.0 / PERIOD_S),
                   "realtime_latency_median_ms": pytest.approx(1e3 * timing.percentile_s(50)),
                   "realtime_latency_p99_ms": pytest.approx(4.0, abs=2e-3),
                   "realtime_latency_max_ms": pytest.approx(4.0),
                   # only the miss at 5.2 s falls in the stand-in's steal (5.0 - 5.5 s)
                   "realtime_host_steal_ms": 250.0, "realtime_missed_ticks_in_host_steal": 1}
    stand_in_plant["report"] = realtime_report(LoopTiming())
    with pytest.raises(BenchmarkError, match="no tick .* was answered"):
        bench_realtime(duration_s=6.0)


def test_dds_benchmarks_interleaves_the_round_trip_and_sets_the_loop_beside_it(monkeypatch):
    """The aggregation alone, with stand-in runs: medians, min, max, summed steal and the round-trip ratios."""
    lockstep = iter([(14.0, 700.0, 10.0), (22.0, 450.0, 30.0), (9.0, 1100.0, 5.0)])
    trips = iter([(500.0, 900.0), (300.0, 2000.0), (400.0, 700.0), (450.0, 1000.0)])
    calls = []

    def bench_lockstep(duration_s):
        calls.append(("lockstep", duration_s))
        factor, tick_us, steal = next(lockstep)
        return {"lockstep_dds_realtime_factor": factor, "lockstep_tick_us": tick_us, "ticks": 2200,
                "host_steal_ms": steal}

    def bench_roundtrip(count):
        calls.append(("roundtrip", count))
        median, p99 = next(trips)
        return {"roundtrip_us_median": median, "roundtrip_us_p99": p99}

    def bench_realtime(duration_s):
        calls.append(("realtime", duration_s))
        return {"realtime_missed_ticks": 2, "realtime_ticks": 6000, "realtime_expected_ticks": 6000,
                "realtime_latency_p99_ms": 1.5, "realtime_missed_ticks_in_host_steal": 2}

    for name, stand_in in (("bench_lockstep", bench_lockstep), ("bench_roundtrip", bench_roundtrip),
                           ("bench_realtime", bench_realtime)):
        monkeypatch.setattr(dds_bench, name, stand_in)
    out = dds_bench.dds_benchmarks()
    count = dds_bench.ROUNDTRIPS
    assert calls == [("lockstep", 22.0), ("roundtrip", count)] * dds_bench.LOCKSTEP_RUNS + [
        ("realtime", 60.0), ("roundtrip", count)]
    # round trip: median of the medians (300, 400, 450, 500) and of the p99s (700, 900, 1000, 2000)
    assert out == {"lockstep_dds_realtime_factor": 14.0, "lockstep_dds_realtime_factor_min": 9.0,
                   "lockstep_dds_realtime_factor_max": 22.0, "lockstep_tick_us": 700.0,
                   "roundtrip_us_median": 425.0, "roundtrip_us_p99": 950.0,
                   "lockstep_tick_over_roundtrip": pytest.approx(700.0 / 425.0), "lockstep_host_steal_ms": 45.0,
                   "realtime_missed_ticks": 2, "realtime_latency_p99_ms": 1.5,
                   "realtime_missed_ticks_in_host_steal": 2,
                   "realtime_latency_p99_over_roundtrip_p99": pytest.approx(1500.0 / 950.0)}


def test_dds_benchmarks_leaves_out_the_lockstep_steal_when_a_run_could_not_sample_it(monkeypatch):
    runs = iter([{"lockstep_dds_realtime_factor": 12.0, "lockstep_tick_us": 800.0, "host_steal_ms": 3.0},
                 {"lockstep_dds_realtime_factor": 11.0, "lockstep_tick_us": 900.0},
                 {"lockstep_dds_realtime_factor": 13.0, "lockstep_tick_us": 700.0, "host_steal_ms": 1.0}])
    monkeypatch.setattr(dds_bench, "bench_lockstep", lambda duration_s: next(runs))
    monkeypatch.setattr(dds_bench, "bench_roundtrip",
                        lambda count: {"roundtrip_us_median": 400.0, "roundtrip_us_p99": 800.0})
    monkeypatch.setattr(dds_bench, "bench_realtime",
                        lambda duration_s: {"realtime_missed_ticks": 0, "realtime_latency_p99_ms": 1.2})
    out = dds_bench.dds_benchmarks()
    assert out["lockstep_dds_realtime_factor"] == 12.0 and "lockstep_host_steal_ms" not in out
    assert out["lockstep_tick_over_roundtrip"] == pytest.approx(2.0)
    assert out["realtime_latency_p99_over_roundtrip_p99"] == pytest.approx(1.5)
