"""write_plots in forked workers writes the same bytes as drawing every figure in this process."""

from __future__ import annotations

import pytest
import numpy as np

from robotino_geom_mpc.offline.plots import FIGURE_SIZES_IN, write_plots
from robotino_geom_mpc.offline.results import RunData

pytestmark = pytest.mark.ros


def _run() -> RunData:
    n = 301
    t = np.arange(n) * 0.01
    w = 2.0 * np.pi / 10.0
    reference = np.c_[0.5 * np.sin(w * t), 0.5 - 0.5 * np.cos(w * t), 0.1 * t]
    pose = reference + np.c_[2e-3 * np.exp(-t), -1e-3 * np.exp(-t), 1e-6 * np.sin(t)]
    currents = 0.5 * np.c_[np.sin(w * t), np.sin(w * t + 2.0), np.sin(w * t - 2.0)]
    return RunData("paper-circle", t, pose, reference, currents, 10.0 * currents, 0.01, 4, 0.86, 24.0)


def test_workers_write_the_same_files_as_one_process(tmp_path):
    run = _run()
    serial = write_plots(run, tmp_path / "serial", settle_time_s=0.5, workers=1)
    parallel = write_plots(run, tmp_path / "parallel", settle_time_s=0.5, workers=3)
    assert [p.name for p in serial] == [p.name for p in parallel] == [f"{s}.png" for s in FIGURE_SIZES_IN]
    for a, b in zip(serial, parallel):
        assert a.read_bytes() == b.read_bytes(), a.name


def test_settle_time_reaches_the_workers(tmp_path):
    """The error plot marks the settle time: a different one gives a different errors.png in the workers too."""
    run = _run()
    first = write_plots(run, tmp_path / "a", settle_time_s=0.5, workers=2)
    second = write_plots(run, tmp_path / "b", settle_time_s=2.0, workers=2)
    differ = {a.name for a, b in zip(first, second) if a.read_bytes() != b.read_bytes()}
    assert differ == {"errors.png"}
