"""The figures of a robustness study (`study`): histograms and each metric against each drawn factor.

Drawn with matplotlib's object API on the Agg canvas (no display), like `plots`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from robotino_geom_mpc.model.encoders import ODOMETRY_MODELS as _ODOMETRY

from robotino_geom_mpc.offline.plots import DPI

__all__ = ["write_study_plots"]

# metric -> (axis label, factor to the plotted unit)
_METRICS = {"rms_position_error_m": ("RMS position error [mm]", 1e3), "peak_current_a": ("peak current [A]", 1.0)}
# draw -> axis label, factor to the plotted unit (friction is drawn log-uniformly: log axis)
_DRAWS = {
    "mass": ("controller mass / true", 1.0),
    "inertia": ("controller yaw inertia / true", 1.0),
    "friction": ("controller friction / true (log)", 1.0),
    "noise_position_m": ("odometry noise [mm]", 1e3),
    "noise_yaw_rad": ("heading noise [mrad]", 1e3),
}


def _figure(width_in: float, height_in: float) -> Figure:
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def write_study_plots(rows: list[dict[str, Any]], out_dir: str | os.PathLike, nominal_current_a: float) -> list[Path]:
    """Write ``histograms.png`` and ``metrics_vs_draws.png`` of the runs without error into `out_dir`.

    Parameters
    ----------
    rows
        The study's rows (`study.COLUMNS`).
    out_dir
        Output folder (exists).
    nominal_current_a
        Drawn as a dashed line on the current axes.

    Returns
    -------
    list of Path
        The two PNGs; none when no run succeeded.
    """
    ok = [row for row in rows if not row["error"]]
    if not ok:
        return []
    out = Path(out_dir)
    odometry = np.array([row["odometry"] for row in ok])
    values = {key: np.array([np.nan if row[key] is None else row[key] for row in ok])
              for key in (*_METRICS, *_DRAWS)}

    hist = _figure(10.0, 4.0)
    for ax, (key, (label, factor)) in zip(hist.subplots(1, len(_METRICS)), _METRICS.items()):
        measured = values[key][np.isfinite(values[key])]  # None: a run no longer than the settle time
        if measured.size == 0:
            continue
        ax.hist(factor * measured, bins=min(50, max(5, measured.size // 10)), color="tab:blue")
        ax.axvline(factor * np.percentile(measured, 95), color="tab:red", ls=":", label="95th percentile")
        if key == "peak_current_a":
            ax.axvline(nominal_current_a, color="k", ls="--", label=f"nominal {nominal_current_a:g} A")
        ax.set_xlabel(label)
        ax.set_ylabel("runs")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    hist.suptitle(f"{len(ok)} runs of {len(rows)}")

    scatter = _figure(3.0 * len(_DRAWS), 6.0)
    axes = scatter.subplots(len(_METRICS), len(_DRAWS), sharey="row")
    for i, (key, (label, factor)) in enumerate(_METRICS.items()):
        for j, (draw, (draw_label, draw_factor)) in enumerate(_DRAWS.items()):
            ax = axes[i, j]
            for model, colour in zip(_ODOMETRY, ("tab:blue", "tab:orange")):
                of_model = odometry == model
                if of_model.any():
                    ax.plot(draw_factor * values[draw][of_model], factor * values[key][of_model], ".", ms=4,
                            alpha=0.6, color=colour, label=f"odometry: {model}")
            if draw == "friction":
                ax.set_xscale("log")
                ax.set_xticks([0.5, 0.7, 1.0, 1.4, 2.0], ["0.5", "0.7", "1", "1.4", "2"])
                ax.minorticks_off()
            if key == "peak_current_a":
                ax.axhline(nominal_current_a, color="k", ls="--", lw=1.0)
            ax.grid(True, alpha=0.3)
            if i == len(_METRICS) - 1:
                ax.set_xlabel(draw_label)
            if j == 0:
                ax.set_ylabel(label)
    axes[0, 0].legend(loc="best", fontsize="small")
    scatter.suptitle("each run's metrics against its draws")

    paths = []
    for stem, fig in (("histograms", hist), ("metrics_vs_draws", scatter)):
        path = out / f"{stem}.png"
        fig.savefig(path, dpi=DPI)
        paths.append(path)
    return paths
