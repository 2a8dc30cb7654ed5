"""The robot-side plan buffer's choice of entry on loss, reordering, duplicates and exhaustion, against hand-worked
sequences; its refusals of malformed plans.
"""

import math

import pytest

from robotino_geom_mpc.network.plan import CommandPlan, PlanBuffer, PlanError

pytestmark = pytest.mark.unit

TS = 0.01


def plan(basis_k, lead, m=4, value=None):
    """A plan computed from the odometry of tick basis_k, first entry at tick basis_k + lead; entry i = (b, i, 0)."""
    times = tuple((basis_k + lead + i) * TS for i in range(m))
    entries = tuple((float(basis_k if value is None else value), float(i), 0.0) for i in range(m))
    return CommandPlan(basis_k * TS, times, entries, TS)


def applied(buffer, k):
    """(basis tick, index) of what the buffer applies at tick k, None for nothing."""
    cmd = buffer.command_at(k * TS)
    return None if cmd is None else (round(cmd.basis_s / TS), cmd.entry_index)


def test_in_order_plans_each_applied_from_its_first_entry():
    buffer = PlanBuffer()
    assert applied(buffer, 0) is None and buffer.exhausted == 0  # nothing received yet: not an exhaustion
    # lead 2: the plan of tick k arrives at tick k + 2 and starts there
    got = []
    for k in range(2, 8):
        assert buffer.offer(plan(k - 2, 2), k * TS) is None
        got.append(applied(buffer, k))
    assert got == [(k - 2, 0) for k in range(2, 8)]


def test_a_lost_plan_is_covered_by_the_previous_one():
    buffer = PlanBuffer()
    buffer.offer(plan(0, 2), 2 * TS)
    # the plans of ticks 1 and 2 are lost: ticks 3 and 4 run on entries 1 and 2 of plan 0
    assert [applied(buffer, k) for k in (2, 3, 4)] == [(0, 0), (0, 1), (0, 2)]
    buffer.offer(plan(3, 2), 5 * TS)
    assert applied(buffer, 5) == (3, 0)


def test_a_late_plan_starts_late_and_an_early_plan_waits_for_its_first_entry():
    buffer = PlanBuffer()
    buffer.offer(plan(0, 2), 2 * TS)
    assert [applied(buffer, k) for k in (2, 3)] == [(0, 0), (0, 1)]
    buffer.offer(plan(1, 2), 4 * TS)  # late by one period: it was due at tick 3, it starts at its entry 1
    assert applied(buffer, 4) == (1, 1)
    early = PlanBuffer()
    early.offer(plan(0, 2), 2 * TS)
    early.offer(plan(1, 5), 3 * TS)  # first entry at tick 6: plan 0 goes on until then
    assert [applied(early, k) for k in (3, 4, 5, 6, 7)] == [(0, 1), (0, 2), (0, 3), (1, 0), (1, 1)]


def test_reordered_and_duplicate_plans_are_ignored():
    buffer = PlanBuffer()
    assert buffer.offer(plan(2, 2), 4 * TS) is None
    assert buffer.offer(plan(1, 2), 4 * TS) == "older"  # overtaken on the way
    assert buffer.offer(plan(2, 2), 5 * TS) == "duplicate"
    assert [applied(buffer, k) for k in (4, 5)] == [(2, 0), (2, 1)]
    assert buffer.refused["older"] == 1 and buffer.refused["duplicate"] == 1 and buffer.accepted == 1


def test_exhaustion_gives_none_and_is_counted():
    buffer = PlanBuffer()
    buffer.offer(plan(0, 1, m=3), 1 * TS)
    assert [applied(buffer, k) for k in (1, 2, 3, 4, 5)] == [(0, 0), (0, 1), (0, 2), None, None]
    assert buffer.exhausted == 2
    buffer.offer(plan(5, 1, m=3), 6 * TS)
    assert applied(buffer, 6) == (5, 0)


def test_entry_boundaries_tolerate_rounding():
    buffer = PlanBuffer()
    p = plan(3, 5)  # entry times 0.08, 0.09, ... built as (3 + 5 + i) * Ts
    buffer.offer(p, 0.08)
    t = 0.03 + 0.05  # the same instant by another sum: 0.08000000000000002
    assert applied(buffer, 0) is None
    assert buffer.command_at(t).entry_index == 0 and buffer.command_at(0.08 - 1e-12).entry_index == 0
    assert buffer.command_at(0.09 - 1e-12).entry_index == 1


@pytest.mark.parametrize("bad, reason", [
    (CommandPlan(0.0, (0.01, 0.02), ((1.0, math.nan, 0.0), (0.0, 0.0, 0.0)), TS), "nan"),
    (CommandPlan(math.inf, (0.01, 0.02), ((0.0, 0.0, 0.0),) * 2, TS), "nan"),
    (CommandPlan(0.0, (0.01, 0.02), ((0.0, 0.0, 0.0),), TS), "length"),
    (CommandPlan(0.0, (0.01,), ((0.0, 0.0),), TS), "length"),
    (CommandPlan(0.0, (), (), TS), "length"),
    (CommandPlan(0.0, (0.02, 0.02), ((0.0, 0.0, 0.0),) * 2, TS), "times"),
    (CommandPlan(0.0, (0.02, 0.01), ((0.0, 0.0, 0.0),) * 2, TS), "times"),
    (CommandPlan(0.0, (-0.01, 0.0), ((0.0, 0.0, 0.0),) * 2, TS), "times"),
    (CommandPlan(0.0, (0.01, 0.02), ((0.0, 0.0, 0.0),) * 2, 0.0), "times"),
    (CommandPlan(10.0, (10.01, 10.02), ((0.0, 0.0, 0.0),) * 2, TS), "future"),
    (CommandPlan(-5.0, (-4.99, 0.5), ((0.0, 0.0, 0.0),) * 2, TS), "past"),
])
def test_malformed_plans_are_refused_and_the_previous_plan_stays(bad, reason):
    buffer = PlanBuffer()
    buffer.offer(plan(0, 1), 1 * TS)
    assert buffer.offer(bad, 1 * TS) == reason
    assert buffer.refused[reason] == 1 and buffer.accepted == 1
    assert applied(buffer, 2) == (0, 1)


def test_bad_settings_are_refused():
    with pytest.raises(PlanError, match="max_age_s"):
        PlanBuffer(max_age_s=0.0)
    with pytest.raises(PlanError, match="max_plans"):
        PlanBuffer(max_plans=0)


def test_a_plan_overtaken_by_one_not_started_yet_still_runs_until_that_one_starts():
    buffer = PlanBuffer()
    buffer.offer(plan(0, 2), 2 * TS)
    assert buffer.offer(plan(2, 3), 3 * TS) is None  # first entry at tick 5
    assert buffer.offer(plan(1, 3), 3 * TS) is None  # overtaken on the way; covers ticks 4 .. 7
    assert [applied(buffer, k) for k in (3, 4, 5, 6)] == [(0, 1), (1, 0), (2, 0), (2, 1)]
    assert buffer.offer(plan(1, 3), 6 * TS) == "duplicate"
    assert buffer.offer(CommandPlan(0.5 * TS, plan(1, 3).times_s, plan(1, 3).entries, TS), 6 * TS) == "older"


def test_an_entry_spans_from_its_start_to_the_next_or_the_plans_end():
    buffer = PlanBuffer()
    buffer.offer(plan(0, 2), 2 * TS)  # entries at ticks 2 .. 5, the last one lasting one period
    entries = [buffer.command_at(k * TS) for k in (2, 3.5, 5)]
    assert [buffer.entry_span(e, TS) for e in entries] == [
        (pytest.approx(2 * TS), pytest.approx(3 * TS)), (pytest.approx(3 * TS), pytest.approx(4 * TS)),
        (pytest.approx(5 * TS), pytest.approx(6 * TS))]
    gone = buffer.command_at(5 * TS)
    buffer.offer(plan(5, 2), 7 * TS)  # the first plan is used up and dropped: an entry of it spans a period
    assert buffer.entry_span(gone, 0.5 * TS) == (pytest.approx(5 * TS), pytest.approx(5.5 * TS))
