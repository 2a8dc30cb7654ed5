"""The emulated link's statistics against its parameters; its refusals of parameters out of range."""

import numpy as np
import pytest

from robotino_geom_mpc.network.link import Link, LinkError, LinkParams

pytestmark = pytest.mark.unit

N = 100_000


def _bursts(lost: np.ndarray) -> np.ndarray:
    """Lengths of the runs of True in `lost`."""
    edges = np.diff(np.concatenate(([0], lost.astype(int), [0])))
    return np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)


@pytest.mark.parametrize("loss, burst", [(0.1, 3.0), (0.05, 1.0), (0.3, 8.0)])
def test_loss_rate_and_mean_burst_length_match_the_parameters(loss, burst):
    link = Link(LinkParams(loss=loss, burst_length=burst), seed=7)
    lost = np.array([not link.transmit(0.01 * k) for k in range(N)])
    bursts = _bursts(lost)
    # bursts are geometric with mean B: the loss rate's std is about sqrt(P B / N) (runs, not packets, are independent)
    assert abs(lost.mean() - loss) < 5 * np.sqrt(loss * burst / N)
    assert abs(bursts.mean() - burst) < 5 * burst / np.sqrt(len(bursts))
    assert link.lost == lost.sum() and link.sent == N
    if burst == 1.0:
        assert bursts.max() == 1  # isolated losses


def test_delay_range_mean_and_duplicates():
    params = LinkParams(delay_s=0.03, jitter_s=0.02, duplicate=0.2)
    link = Link(params, seed=3)
    delays, copies = [], []
    for k in range(N // 4):
        times = link.transmit(0.01 * k)
        copies.append(len(times))
        delays += [t - 0.01 * k for t in times]
    delays = np.array(delays)
    assert delays.min() >= 0.03 - 1e-12 and delays.max() <= 0.05 + 1e-12
    # uniform on [D, D + J]: mean D + J / 2, std J / sqrt(12)
    assert abs(delays.mean() - params.mean_delay_s) < 5 * 0.02 / np.sqrt(12 * len(delays))
    assert abs(delays.std() - 0.02 / np.sqrt(12)) < 2e-4
    assert set(copies) == {1, 2}
    assert abs(np.mean(np.array(copies) == 2) - 0.2) < 5 * np.sqrt(0.2 * 0.8 / len(copies))


def test_jitter_reorders_and_a_fixed_delay_does_not():
    def order(params):
        link = Link(params, seed=11)
        arrivals = [(link.transmit(0.01 * k)[0], k) for k in range(2000)]
        return [k for _, k in sorted(arrivals)]
    assert order(LinkParams(delay_s=0.03)) == list(range(2000))
    reordered = order(LinkParams(delay_s=0.03, jitter_s=0.02))
    inversions = sum(a > b for a, b in zip(reordered, reordered[1:]))
    # two packets 10 ms apart with jitters uniform on [0, 20 ms] swap with probability 1/8
    assert abs(inversions / 2000 - 0.125) < 0.03


def test_same_seed_same_deliveries_other_seed_others():
    params = LinkParams(delay_s=0.015, jitter_s=0.015, loss=0.05, burst_length=3.0, duplicate=0.01)
    a, b, c = (Link(params, s) for s in (1, 1, 2))
    runs = [[link.transmit(0.01 * k) for k in range(500)] for link in (a, b, c)]
    assert runs[0] == runs[1] and runs[0] != runs[2]


def test_a_disabled_link_delivers_at_once():
    link = Link(LinkParams(), seed=0)
    assert not LinkParams().enabled and LinkParams(loss=0.1).enabled
    assert all(link.transmit(0.01 * k) == [0.01 * k] for k in range(100))


@pytest.mark.parametrize("kwargs, name", [
    ({"loss": 1.0}, "link.loss"), ({"loss": -0.1}, "link.loss"), ({"delay_s": -1e-3}, "link.delay_s"),
    ({"jitter_s": float("nan")}, "link.jitter_s"), ({"burst_length": 0.5}, "link.burst_length"),
    ({"duplicate": 1.5}, "link.duplicate"), ({"loss": 0.6, "burst_length": 1.0}, "link.loss"),
    ({"delay_s": 11.0}, "link.delay_s"),
])
def test_out_of_range_parameters_are_refused_by_name(kwargs, name):
    with pytest.raises(LinkError, match=name.replace(".", r"\.")):
        LinkParams(**kwargs)
