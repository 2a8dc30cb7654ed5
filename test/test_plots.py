"""write_plots: the PNGs exist, decode with an independent reader, have the figure's size and content."""

from __future__ import annotations

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from robotino_geom_mpc.offline.plots import DPI, FIGURE_SIZES_IN, THETA_MIN_HALF_SPAN_RAD, theta_limits, write_plots
from robotino_geom_mpc.offline.results import RunData

pytestmark = [pytest.mark.unit, pytest.mark.slow]  # each test draws a simulated run's figures

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    n = 501
    t = np.arange(n) * 0.01
    w = 2.0 * np.pi / 10.0
    reference = np.c_[0.5 * np.sin(w * t), 0.5 - 0.5 * np.cos(w * t), np.zeros(n)]
    pose = reference + np.c_[2e-3 * np.exp(-t), -1e-3 * np.exp(-t), 1e-6 * np.sin(t)]
    currents = 0.5 * np.c_[np.sin(w * t), np.sin(w * t + 2.0), np.sin(w * t - 2.0)]
    currents[:5] += 1.2  # start transient above the nominal current
    run = RunData("paper-circle", t, pose, reference, currents, 10.0 * currents, 0.01, 4, 0.86, 24.0)
    out = tmp_path_factory.mktemp("plots") / "figs"
    return out, write_plots(run, out)


def test_one_png_per_figure_in_out_dir(written):
    out, paths = written
    assert [p.name for p in paths] == [f"{stem}.png" for stem in FIGURE_SIZES_IN]
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in paths)
    for path in paths:
        assert path.read_bytes()[:8] == PNG_SIGNATURE


@pytest.mark.parametrize("stem", list(FIGURE_SIZES_IN))
def test_png_decodes_with_figure_size_and_is_not_blank(written, stem):
    _, paths = written
    image = mpimg.imread(next(p for p in paths if p.stem == stem))
    width_in, height_in = FIGURE_SIZES_IN[stem]
    assert image.shape[:2] == (round(height_in * DPI), round(width_in * DPI))
    rgb = image[..., :3]
    # mostly white background with drawn lines: some dark pixels, many white ones
    assert np.mean(rgb.min(axis=2) > 0.95) > 0.5
    assert np.mean(rgb.max(axis=2) < 0.3) > 0.001


def test_no_pyplot_figures_left_open(written):
    assert plt.get_fignums() == []


@pytest.mark.parametrize(("values", "expected"), [
    (np.array([0.0, 1e-18, -2e-18]), (-5e-19 - 1e-3, -5e-19 + 1e-3)),  # numerical noise about 0: +-1 mrad
    (np.full(4, 3.0), (3.0 - 1e-3, 3.0 + 1e-3)),  # a constant heading: centred on it
    (np.array([0.0, 1.0]), None),  # a real motion: matplotlib's autoscale
])
def test_theta_axis_has_a_minimum_span(values, expected):
    limits = theta_limits(values)
    assert limits == (None if expected is None else pytest.approx(expected, rel=0, abs=1e-15))
    if limits is not None:
        assert limits[1] - limits[0] == pytest.approx(2 * THETA_MIN_HALF_SPAN_RAD)


def test_theta_figure_of_a_constant_heading_spans_two_milliradians(tmp_path):
    """The drawn axis: +-1 mrad about a heading whose noise is 1e-18 rad, not the noise autoscaled to fill it."""
    from robotino_geom_mpc.offline.plots import _figure, _theta

    n = 50
    t = np.arange(n) * 0.01
    noise = 1e-18 * np.sin(np.arange(n))
    reference = np.c_[t, t, np.zeros(n)]
    run = RunData("paper-circle", t, reference + np.c_[0 * t, 0 * t, noise], reference, np.zeros((n, 3)),
                  np.zeros((n, 3)), 0.01, 4, 0.86, 24.0)
    fig = _figure("theta")
    _theta(run, fig)
    low, high = fig.axes[0].get_ylim()
    assert high - low == pytest.approx(2e-3, rel=1e-9)
