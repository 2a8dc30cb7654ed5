"""`LoopTiming` against the definition worked out by hand on event sequences: answers, misses, percentiles."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotino_sim_node.loop_timing import LockstepPace, LoopTiming

pytestmark = pytest.mark.unit


def test_counts_from_the_first_answered_tick():
    timing = LoopTiming()
    timing.published(0.00)  # unanswered before the loop runs: not a miss
    timing.published(0.01)
    timing.command(0.0112)  # answers tick 1 after 1.2 ms
    timing.command(0.0115)  # a second command in the same tick is not an answer
    timing.published(0.02)  # unanswered: a miss once the next tick goes out
    timing.published(0.03)
    timing.command(0.0305)
    timing.published(0.04)  # the run ends before its answer: neither answered nor missed
    assert (timing.answered, timing.missed) == (2, 1)
    assert timing.max_latency_s == pytest.approx(1.2e-3)
    assert timing.percentile_s(100) == pytest.approx(1.2e-3)  # the upper edge of the 1 us bin of 1.2 ms
    assert "2 ticks answered, 1 missed" in timing.summary()
    assert timing.missed_at == [(0.02, pytest.approx(0.01))]  # the missed tick's odometry, on the steady clock
    assert "first answer at steady time 0.011200 s" in timing.summary()
    assert "(s after the first answer: ms to the next odometry) 0.008800: 10.000" in timing.summary()


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(min_value=0.0, max_value=0.05), min_size=1, max_size=300), st.sampled_from([50, 90, 99]))
def test_percentiles_are_the_nearest_rank_to_one_bin(latencies, q):
    timing = LoopTiming(bin_s=1e-6, max_s=0.1)
    for k, latency in enumerate(latencies):
        timing.published(float(k))
        timing.command(k + latency)
    expected = np.percentile(np.array([(k + lat) - k for k, lat in enumerate(latencies)]), q,
                             method="inverted_cdf")
    assert expected <= timing.percentile_s(q) + 1e-9 and timing.percentile_s(q) <= expected + 1e-6 + 1e-9


def test_latencies_beyond_the_histogram_go_to_the_last_bin():
    timing = LoopTiming(bin_s=1e-3, max_s=0.01)
    timing.published(0.0)
    timing.command(0.5)
    assert timing.max_latency_s == 0.5 and timing.percentile_s(50) == pytest.approx(0.011)


def test_empty_and_bad_settings():
    assert np.isnan(LoopTiming().percentile_s(99))
    with pytest.raises(ValueError):
        LoopTiming(bin_s=0.2, max_s=0.1)


def test_lockstep_pace_spaces_ticks_by_the_factor_and_restarts_after_a_stall():
    pace = LockstepPace(2.0, 0.01)  # a tick every 5 ms at most
    assert pace.delay(10.0) == 0.0  # the first goes out at once
    assert pace.delay(10.001) == pytest.approx(0.004)  # its slot: 10.005
    assert pace.delay(10.0051) == pytest.approx(0.0049)  # answered after its slot: the next is at 10.010
    assert pace.delay(10.5) == 0.0  # a stall: at once, and the schedule starts again from there (no burst)
    assert pace.delay(10.5001) == pytest.approx(0.0049)
    unpaced = LockstepPace(0.0, 0.01)
    assert [unpaced.delay(t) for t in (1.0, 1.0, 1.0001)] == [0.0, 0.0, 0.0]


@settings(max_examples=30, deadline=None)
@given(st.lists(st.one_of(st.none(), st.floats(min_value=0.0, max_value=0.009)), min_size=1, max_size=200),
       st.sampled_from([0.05, 0.1, 0.37]))
def test_windows_hold_the_figures_of_their_ticks(answers, window_s):
    """Ticks every 10 ms, answered after the given latency or not (None); each window's counts and percentiles are
    those of the ticks between its opening odometry and the next window's, computed here from the list.
    """
    timing = LoopTiming(bin_s=1e-6, max_s=0.1, window_s=window_s)
    for k, latency in enumerate(answers):
        timing.published(0.01 * k)
        if latency is not None:
            timing.command(0.01 * k + latency)
    windows = timing.figures()["windows"]
    assert sum(w["ticks"] for w in windows) == len(answers)
    assert sum(w["answered"] for w in windows) == timing.answered
    # a miss is counted when the next tick goes out, in the window of the missed tick; the last is never one
    assert sum(w["missed"] for w in windows) == timing.missed
    first = next((k for k, a in enumerate(answers) if a is not None), len(answers))
    start = 0
    for w in windows:
        ticks = answers[start:start + w["ticks"]]
        assert w["start_steady_s"] == pytest.approx(0.01 * start)
        assert w["start_steady_s"] + window_s >= w["end_steady_s"] - 0.01 - 1e-9 or w is windows[-1]
        assert w["answered"] == sum(a is not None for a in ticks)
        missed = sum(a is None and first < start + i < len(answers) - 1 for i, a in enumerate(ticks))
        assert w["missed"] == missed
        latencies = np.array([a for a in ticks if a is not None])
        if latencies.size:
            for q in (50, 99, 99.9):
                expected = np.percentile(latencies, q, method="inverted_cdf")
                got = w["latency_ms"][f"p{q:g}"] * 1e-3
                assert expected <= got + 1e-9 and got <= expected + 1e-6 + 1e-9
            assert w["latency_ms"]["max"] * 1e-3 == pytest.approx(latencies.max())
        else:
            assert w["latency_ms"] is None
        start += w["ticks"]


def test_no_windows_without_a_window_length():
    timing = LoopTiming()
    timing.published(0.0)
    timing.command(0.001)
    assert "windows" not in timing.figures()
