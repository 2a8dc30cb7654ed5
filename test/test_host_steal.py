"""`host_steal` against /proc/stat lines written by hand and a file whose steal changes while it is sampled."""

import os
import time

import pytest

from robotino_geom_mpc.bench.host_steal import PROC_STAT, StealSampler, read_steal_s
from recording_helpers import wait_for

pytestmark = pytest.mark.unit

HZ = os.sysconf("SC_CLK_TCK")
HANG_S = 60.0  # waits on the sampler's thread end at this only if it hangs


def stat_file(path, steal_jiffies: int) -> None:
    """Write a /proc/stat look-alike atomically (the sampler may be reading it)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(f"cpu  1880659 1621 196854 2752319 6896 0 13518 {steal_jiffies} 0 0\n"
                   f"cpu0 940000 800 98000 1376000 3400 0 6700 {steal_jiffies // 2} 0 0\nintr 1 2 3\n")
    os.replace(tmp, path)


def test_steal_is_the_eighth_value_of_the_cpu_line_in_clock_ticks(tmp_path):
    path = tmp_path / "stat"
    stat_file(path, 105505)
    assert read_steal_s(path) == pytest.approx(105505 / HZ)


@pytest.mark.parametrize("first_line, reason", [
    ("intr 1 2 3 4 5 6 7 8 9\n", "aggregate cpu line"),
    ("cpu  1 2 3 4 5 6 7\n", "aggregate cpu line"),  # a kernel without the steal column
    ("cpu  1 2 3 4 5 6 7 x 0 0\n", "not an integer"),
    ("", "aggregate cpu line"),
])
def test_a_malformed_stat_file_is_named(tmp_path, first_line, reason):
    path = tmp_path / "stat"
    path.write_text(first_line)
    with pytest.raises(ValueError, match=reason):
        read_steal_s(path)


def test_without_the_file_there_is_nothing_to_sample(tmp_path):
    assert read_steal_s(tmp_path / "missing") is None
    with StealSampler(path=tmp_path / "missing") as sampler:
        time.sleep(0.02)
    assert not sampler.available and sampler.samples == [] and sampler.total_s() == 0.0
    assert sampler.during(0.0, 1e9) == 0.0


class SteppedClock:
    """The sampler's steady clock, moved by the test: every sample's time is known."""

    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def test_steal_is_placed_in_the_window_where_it_happened(tmp_path):
    path = tmp_path / "stat"
    stat_file(path, 1000)
    clock = SteppedClock(100.0)
    # the test takes every sample itself, 5 ms apart on its clock (the thread's interval never comes)
    with StealSampler(interval_s=3600.0, path=path, clock=clock) as sampler:
        for k in range(1, 21):
            clock.now = 100.0 + 0.005 * k
            sampler.sample()
        before = clock.now + 0.001
        stat_file(path, 1000 + 3 * HZ // 100)  # the host takes 30 ms, between the samples at 100.100 and 100.105
        after = clock.now + 0.002
        for k in range(21, 41):
            clock.now = 100.0 + 0.005 * k
            sampler.sample()
    assert sampler.total_s() == pytest.approx(0.03)
    assert sampler.during(before, after) == pytest.approx(0.03)
    assert sampler.during(100.1, 100.105) == pytest.approx(0.03)  # window on the two samples around it
    assert sampler.during(sampler.samples[0][0], before - 0.03) == 0.0  # brackets reach one sample beyond
    assert sampler.during(after + 0.03, sampler.samples[-1][0]) == 0.0
    assert sampler.during(100.105, 100.2) == 0.0 and sampler.during(100.0, 100.1) == 0.0
    assert sampler.during(after, before) == 0.0  # an empty window
    assert sampler.during(50.0, 150.0) == pytest.approx(0.03)  # outside the sampled span: clipped to it
    assert [t for t, _ in sampler.samples] == [pytest.approx(100.0 + 0.005 * k) for k in range(41)] + [
        pytest.approx(100.2)]  # one at entry, the test's 40, one at exit
    assert not sampler._thread.is_alive()


def test_the_thread_samples_until_the_exit(tmp_path):
    path = tmp_path / "stat"
    stat_file(path, 1000)
    with StealSampler(interval_s=0.005, path=path) as sampler:
        wait_for(lambda: len(sampler.samples) >= 5, HANG_S, "the entry's sample and four of the thread's")
        stat_file(path, 1000 + HZ)
        count = len(sampler.samples)
        wait_for(lambda: len(sampler.samples) > count, HANG_S, "a sample of the new steal")
    times = [t for t, _ in sampler.samples]
    assert times == sorted(times) and sampler.total_s() == pytest.approx(1.0)
    assert not sampler._thread.is_alive()


def test_a_file_that_turns_bad_while_sampled_ends_sampling_with_the_reason(tmp_path):
    path = tmp_path / "stat"
    stat_file(path, 1000)
    with StealSampler(interval_s=0.005, path=path) as sampler:
        wait_for(lambda: len(sampler.samples) >= 2, HANG_S, "two samples")
        path.write_text("garbage\n")
        wait_for(lambda: not sampler._thread.is_alive(), HANG_S, "the thread to stop on the bad file by itself")
        kept = len(sampler.samples)
    assert not sampler.available and "aggregate cpu line" in str(sampler.error)
    assert len(sampler.samples) == kept >= 2 and sampler.total_s() == 0.0  # what came before is kept


@pytest.mark.skipif(not PROC_STAT.exists(), reason="no /proc/stat (not Linux)")
def test_this_machines_steal_never_decreases():
    with StealSampler(interval_s=0.005) as sampler:
        time.sleep(0.05)
    values = [s for _, s in sampler.samples]
    assert sampler.available and values == sorted(values) and sampler.total_s() >= 0.0


def test_bad_interval():
    with pytest.raises(ValueError, match="interval_s"):
        StealSampler(interval_s=0.0)
