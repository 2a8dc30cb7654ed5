"""write_plots: the PNGs exist, decode with an independent reader, have the figure's size and content."""

from __future__ import annotations

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from robotino_geom_mpc.offline.plots import DPI, FIGURE_SIZES_IN, write_plots
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
