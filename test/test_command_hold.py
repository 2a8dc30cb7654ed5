"""`CommandHold` against the grid worked out by hand: runs of constant voltage, the watchdog's first stale point."""

import numpy as np
import pytest

from robotino_geom_mpc.loop.command_hold import MAX_CHUNK, CommandHold

pytestmark = pytest.mark.unit


def _runs(hold, target, timeout_s):
    runs = []
    timed_out = hold.advance(target, timeout_s, lambda volts, seconds: runs.append((tuple(volts), seconds)))
    return runs, timed_out


def test_a_held_command_runs_until_it_is_older_than_the_timeout_then_zero_volts_once():
    hold = CommandHold(started_at=2.0, dt=0.001)
    runs, timed_out = _runs(hold, 4, 0.1)
    assert runs == [((0.0, 0.0, 0.0), pytest.approx(0.004))] and not timed_out  # nothing held yet: zero volts
    hold.hold((1.0, -2.0, 3.0), 2.0035)  # 3.5 grid steps in
    runs, timed_out = _runs(hold, 120, 0.1)
    # stale from the first grid point after 2.0035 + 0.1 s: 104 (0.104 s > 0.1035 s > 0.103 s)
    fresh = [volts for volts, _ in runs[:10]]
    assert fresh == [(1.0, -2.0, 3.0)] * 10 and [s for _, s in runs[:10]] == pytest.approx([MAX_CHUNK * 0.001] * 10)
    assert runs[10:] == [((0.0, 0.0, 0.0), pytest.approx(0.010)), ((0.0, 0.0, 0.0), pytest.approx(0.006))]
    assert timed_out and hold.grid == 120
    runs, timed_out = _runs(hold, 130, 0.1)
    assert runs == [((0.0, 0.0, 0.0), pytest.approx(0.010))] and not timed_out  # reported once per command
    hold.hold((0.5, 0.5, 0.5), 2.130)
    runs, timed_out = _runs(hold, 135, 0.1)
    assert runs == [((0.5, 0.5, 0.5), pytest.approx(0.005))] and not timed_out
    assert np.sum([s for _, s in runs]) == pytest.approx(0.005)


def test_a_run_ending_on_the_stale_point_is_not_a_timeout_yet():
    hold = CommandHold(started_at=0.0, dt=0.001)
    hold.hold((1.0, 1.0, 1.0), 0.0005)
    runs, timed_out = _runs(hold, 11, 0.01)  # stale from grid point 11: up to it the command holds
    assert [v for v, _ in runs] == [(1.0, 1.0, 1.0)] * 2 and sum(s for _, s in runs) == pytest.approx(0.011)
    assert not timed_out
    runs, timed_out = _runs(hold, 12, 0.01)
    assert runs == [((0.0, 0.0, 0.0), pytest.approx(0.001))] and timed_out
