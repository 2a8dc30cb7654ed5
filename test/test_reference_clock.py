"""The trajectory node's timing in-process (`loop.reference_clock`), with a hand-driven clock: the realtime start
(settle, hold, enable, disable) and the lockstep previews of each /clock (ahead, repeats, jumps, gap fill, a late
subscription), against the protocol the node's docstring states, written out tick by tick.
"""

from __future__ import annotations

import pytest

from robotino_geom_mpc.loop.reference_clock import GAP_FILL_TICKS, LockstepPreviews, RealtimeStart, Tick, path_stamps

pytestmark = pytest.mark.unit

MS = 1_000_000
TS = 10 * MS


def _holds() -> bool:  # the node's start condition holds (a graph query there)
    return True


def _lapsed() -> bool:
    return False


def test_realtime_starts_once_the_condition_has_held_for_the_settle_time():
    start = RealtimeStart(1.0, start_on_enable=False)
    assert start.tick(0, ready=_lapsed) is Tick.WAIT and start.reference_s(5 * MS) == 0.0
    assert start.tick(10 * MS, ready=_holds) is Tick.WAIT  # the settle counts from here
    assert start.tick(900 * MS, ready=_holds) is Tick.WAIT
    assert start.tick(950 * MS, ready=_lapsed) is Tick.WAIT  # a lapse starts the settle over
    assert start.tick(1000 * MS, ready=_holds) is Tick.WAIT
    assert start.tick(1999 * MS, ready=_holds) is Tick.WAIT
    assert start.tick(2000 * MS, ready=_holds) is Tick.START and start.start_ns == 2000 * MS
    asked: list[int] = []
    assert start.tick(2010 * MS, ready=lambda: asked.append(1) or False) is Tick.RUN  # started: the condition
    assert asked == []  # no longer matters, nor is it asked (the node's is a graph query)
    assert start.reference_ns(2013 * MS) == 13 * MS and start.reference_s(2013 * MS) == pytest.approx(0.013)
    assert start.on_enabled(True, 2020 * MS, ready=_holds) is None  # without start_on_enable it changes nothing
    assert start.start_ns == 2000 * MS


def test_start_on_enable_holds_starts_at_the_enable_and_holds_again_at_a_disable():
    start = RealtimeStart(0.5, start_on_enable=True)
    assert start.tick(0, ready=_holds) is Tick.WAIT
    assert start.on_enabled(True, 100 * MS, ready=_holds) is None  # enabled before the settle: the tick starts
    assert start.on_enabled(False, 200 * MS, ready=_holds) is None  # (not started: nothing to stop)
    assert start.tick(500 * MS, ready=_holds) is Tick.HOLD  # settled, not enabled: the start point at rest
    assert start.tick(510 * MS, ready=_holds) is Tick.HOLD
    assert start.on_enabled(True, 513 * MS, ready=_holds) is Tick.START and start.start_ns == 513 * MS  # the enable
    assert start.on_enabled(True, 514 * MS, ready=_holds) is None  # the same state again
    assert start.tick(520 * MS, ready=_holds) is Tick.RUN and start.reference_ns(520 * MS) == 7 * MS
    assert start.on_enabled(False, 900 * MS, ready=_holds) is Tick.HOLD and start.start_ns is None
    assert start.tick(910 * MS, ready=_holds) is Tick.HOLD
    assert start.on_enabled(True, 915 * MS, ready=_lapsed) is None  # no controller or odometry: not settled
    assert start.tick(920 * MS, ready=_holds) is Tick.WAIT  # the settle starts over
    assert start.tick(1420 * MS, ready=_holds) is Tick.START and start.start_ns == 1420 * MS  # enabled already


def test_lockstep_previews_go_out_one_tick_ahead_with_repeats_jumps_and_gaps():
    ticks = LockstepPreviews(0.01)
    assert ticks.on_matched() == [] and ticks.last_clock_s() is None and ticks.reference_s() == 0.0

    def clock(now: int) -> list[int]:
        stamps = ticks.on_clock(now)
        for stamp in stamps:
            ticks.published(stamp)
        return stamps

    assert clock(0) == [0, TS]  # the first tick: its own preview, then the next's
    assert clock(TS) == [2 * TS]  # its own went out ahead
    assert clock(TS) == [TS, 2 * TS]  # a resent tick: both again
    assert clock(2 * TS) == [3 * TS]
    assert clock(5 * TS) == [3 * TS + TS, 5 * TS, 6 * TS]  # a jump: the skipped tick 4, then 5 and 6
    assert ticks.reference_s() == pytest.approx(0.06) and ticks.last_clock_s() == pytest.approx(0.05)
    assert ticks.on_matched() == [5 * TS, 6 * TS]  # a new subscription: the current tick's previews again
    far = 6 * TS + (GAP_FILL_TICKS + 1) * TS
    assert clock(far) == [far, far + TS]  # more than GAP_FILL_TICKS skipped: not filled


def test_the_grid_and_the_path_stamps():
    ticks = LockstepPreviews(0.01)
    assert [ticks.grid_index(t) for t in (0, 3 * TS, 3 * TS + 1, -TS)] == [0, 3, None, None]
    assert path_stamps(7 * MS, [0.0, 0.01, 0.0125]) == [7 * MS, 17 * MS, 19_500_000]
