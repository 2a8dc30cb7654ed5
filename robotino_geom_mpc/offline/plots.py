"""The figures of a run: the paper's Figs. 4-6 (path, theta, currents) plus voltages and tracking errors.

A run measured by odometry alone (``run.meta["truth"] == "odometry"``: a real robot's recording) is labelled so;
one without wheel currents gets ``commands.png`` instead of ``currents.png``: the commanded twist and the wheel
speeds it asks for (`write_plots`'s ``commands``).

Figures are drawn with matplotlib's object API on the Agg canvas (no
display, no pyplot global state) and written as PNG; on a machine with
several cores, by forked worker processes (a figure costs 0.2-0.5 s of
CPU, mostly layout and rasterising, and `run` waits for them).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from robotino_geom_mpc.offline.results import RunData

__all__ = ["COMMANDS_SIZE_IN", "DPI", "FIGURE_SIZES_IN", "THETA_MIN_HALF_SPAN_RAD", "theta_limits", "write_plots"]

DPI = 100
# file stem -> figure size (width, height) in inches; the PNG is DPI times larger
FIGURE_SIZES_IN: dict[str, tuple[float, float]] = {
    "xy_path": (6.0, 6.0),
    "theta": (8.0, 4.0),
    "currents": (8.0, 4.5),
    "voltages": (8.0, 4.5),
    "errors": (8.0, 6.0),
}
COMMANDS_SIZE_IN = (8.0, 6.0)  # commands.png, drawn instead of currents.png for a run without currents
THETA_MIN_HALF_SPAN_RAD = 1e-3  # theta.png shows at least +-1 mrad: a constant heading's numerical noise reads as such
_WHEEL_COLOURS = ("tab:blue", "tab:orange", "tab:green")
_PREFIXES = (("", 1.0), ("m", 1e3), ("\u00b5", 1e6), ("n", 1e9))


def _prefix(values: np.ndarray) -> tuple[str, float]:
    """The SI prefix (and its factor) that shows the largest |value| between 1 and 1000."""
    peak = float(np.abs(values).max())
    for prefix, factor in _PREFIXES:
        if peak * factor >= 1.0:
            return prefix, factor
    return _PREFIXES[-1] if peak > 0.0 else _PREFIXES[1]


def _figure(stem: str) -> Figure:
    fig = Figure(figsize=COMMANDS_SIZE_IN if stem == "commands" else FIGURE_SIZES_IN[stem], dpi=DPI,
                 layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _pose_label(run: RunData) -> tuple[str, str]:
    """(legend label of the pose, title suffix): "robot", or "odometry" for a run measured by odometry alone."""
    if run.meta.get("truth") == "odometry":
        return "odometry", " (odometry; no ground truth)"
    return "robot", ""


def _xy_path(run: RunData, fig: Figure) -> None:
    label, suffix = _pose_label(run)
    ax = fig.add_subplot()
    ax.plot(run.reference[:, 0], run.reference[:, 1], "k--", lw=1.2, label="reference")
    ax.plot(run.pose[:, 0], run.pose[:, 1], color="tab:red", lw=1.0, label=label)
    ax.plot(*run.pose[0, :2], "o", color="tab:red", ms=5, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{run.scenario}: path in the plane{suffix} (cf. paper Fig. 4)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")


def theta_limits(values: np.ndarray) -> tuple[float, float] | None:
    """The theta axis' limits when `values` span less than 2 `THETA_MIN_HALF_SPAN_RAD` (centred on their middle),
    None when they span more (matplotlib's autoscale then).
    """
    low, high = float(np.min(values)), float(np.max(values))
    if high - low >= 2.0 * THETA_MIN_HALF_SPAN_RAD:
        return None
    middle = 0.5 * (low + high)
    return middle - THETA_MIN_HALF_SPAN_RAD, middle + THETA_MIN_HALF_SPAN_RAD


def _theta(run: RunData, fig: Figure) -> None:
    label, suffix = _pose_label(run)
    ax = fig.add_subplot()
    ax.plot(run.t, run.reference[:, 2], "k--", lw=1.2, label=r"reference $\theta_d$")
    ax.plot(run.t, run.pose[:, 2], color="tab:red", lw=1.0, label=rf"{label} $\theta$")
    limits = theta_limits(np.concatenate((run.reference[:, 2], run.pose[:, 2])))
    if limits is not None:  # a (nearly) constant heading: its noise must not fill the axis
        ax.set_ylim(*limits)
        ax.ticklabel_format(axis="y", useOffset=False)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(r"$\theta$ [rad]")
    ax.set_title(f"{run.scenario}: heading{suffix} (cf. paper Fig. 5)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")


def _limited(
    run: RunData, fig: Figure, series: np.ndarray, limit: float, what: str, unit: str, limit_label: str
) -> Axes:
    ax = fig.add_subplot()
    for k in range(3):
        ax.plot(run.t, series[:, k], color=_WHEEL_COLOURS[k], lw=1.0, label=f"wheel {k + 1}")
    for sign in (1.0, -1.0):
        ax.axhline(sign * limit, color="k", ls="--", lw=1.0, label=limit_label if sign > 0 else None)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{what} [{unit}]")
    ax.grid(True, alpha=0.3)
    top = 1.4 * max(limit, float(np.abs(series).max()))  # headroom above the limit lines for the legend
    ax.set_ylim(-top, top)
    ax.legend(loc="upper center", ncols=4, fontsize="small")
    return ax


def _currents(run: RunData, fig: Figure) -> None:
    ax = _limited(run, fig, run.currents, run.nominal_current_a, "current", "A",
                  rf"$\pm I_{{nom}}$ = {run.nominal_current_a:g} A")
    ax.set_title(f"{run.scenario}: wheel currents (cf. paper Fig. 6)")


def _voltages(run: RunData, fig: Figure) -> None:
    ax = _limited(run, fig, run.voltages, run.supply_voltage_v, "voltage", "V",
                  rf"$\pm U_{{supply}}$ = {run.supply_voltage_v:g} V")
    ax.set_title(f"{run.scenario}: wheel voltages")


def _errors(run: RunData, fig: Figure, settle_time_s: float) -> None:
    err = run.errors()
    pos_prefix, pos_factor = _prefix(err[:, :2])
    theta_prefix, theta_factor = _prefix(err[:, 2])
    ax_pos, ax_theta = fig.subplots(2, 1, sharex=True)
    ax_pos.plot(run.t, pos_factor * err[:, 0], color="tab:blue", lw=1.0, label=r"$x - x_d$")
    ax_pos.plot(run.t, pos_factor * err[:, 1], color="tab:orange", lw=1.0, label=r"$y - y_d$")
    ax_pos.set_ylabel(f"position error [{pos_prefix}m]")
    ax_pos.set_title(f"{run.scenario}: tracking errors")
    ax_theta.plot(run.t, theta_factor * err[:, 2], color="tab:green", lw=1.0, label=r"$\theta - \theta_d$")
    ax_theta.set_ylabel(f"heading error [{theta_prefix}rad]")
    ax_theta.set_xlabel("time [s]")
    for ax in (ax_pos, ax_theta):
        ax.axvline(run.t[0] + settle_time_s, color="k", ls=":", lw=1.0, label=f"settle time {settle_time_s:g} s")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")


def _commands(run: RunData, fig: Figure, commands: tuple[np.ndarray, np.ndarray]) -> None:
    """The commanded body twist and the wheel speeds it asks for (a recording without wheel currents)."""
    twist, wheels = commands
    ax_twist, ax_wheels = fig.subplots(2, 1, sharex=True)
    for k, label in enumerate((r"$v_x$ [m/s]", r"$v_y$ [m/s]", r"$\dot\theta$ [rad/s]")):
        ax_twist.plot(run.t, twist[:, k], color=_WHEEL_COLOURS[k], lw=1.0, label=label)
        ax_wheels.plot(run.t, wheels[:, k], color=_WHEEL_COLOURS[k], lw=1.0, label=f"wheel {k + 1}")
    ax_twist.set_ylabel("body twist")
    ax_twist.set_title(f"{run.scenario}: commanded twist (cmd_vel); no wheel currents recorded (cf. paper Fig. 6)")
    ax_wheels.set_ylabel("wheel speed [rad/s]")
    ax_wheels.set_xlabel("time [s]")
    for ax in (ax_twist, ax_wheels):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small", ncols=3)


# file stem -> drawing function (``errors`` also takes the settle time, ``commands`` the commands: `_write`)
_DRAW: dict[str, Callable[[RunData, Figure], None]] = {"xy_path": _xy_path, "theta": _theta, "currents": _currents,
                                                      "voltages": _voltages}


def _write(stem: str, run: RunData, path: Path, settle_time_s: float,
           commands: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    fig = _figure(stem)
    if stem == "errors":
        _errors(run, fig, settle_time_s)
    elif stem == "commands":
        assert commands is not None  # `write_plots` draws commands.png only with them
        _commands(run, fig, commands)
    else:
        _DRAW[stem](run, fig)
    # the constrained layout once, then fixed: savefig with a layout engine draws the figure twice (a draw to
    # lay it out, then the one rendered), 10-15 % of a figure's time; the PNG is the same byte for byte
    engine = fig.get_layout_engine()
    if engine is not None:
        engine.execute(fig)
    fig.set_layout_engine("none")
    fig.savefig(path, dpi=DPI)
    return path


def write_plots(run: RunData, out_dir: str | os.PathLike, settle_time_s: float = 1.0,
                workers: int | None = None, commands: tuple[np.ndarray, np.ndarray] | None = None,
                voltages: bool = True) -> list[Path]:
    """Write the PNGs of a run into `out_dir` (created if needed).

    Parameters
    ----------
    run
        The run.
    out_dir
        Output folder.
    settle_time_s
        Marked in the error plot: metrics count position errors after it.
    workers
        Processes drawing the figures (default: the usable cores, at most 3); with 1, or where `fork`
        is not available, this process draws them all. The files are the same either way.
    commands
        A run without wheel currents (a real robot's recording): the commanded body twist (v_x, v_y [m/s],
        theta' [rad/s]) and the wheel speeds [rad/s], shape (n, 3) each, drawn as ``commands.png`` instead of
        ``currents.png``.
    voltages
        False: the run has no voltages (its ``voltages`` stand in), no ``voltages.png``.

    Returns
    -------
    list of Path
        ``xy_path.png`` (paper Fig. 4), ``theta.png`` (Fig. 5),
        ``currents.png`` with +-I_nom (Fig. 6) or ``commands.png``, ``voltages.png`` with
        +-supply, ``errors.png`` (x, y, theta errors), in that order.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stems = [stem for stem in ("xy_path", "theta", "currents" if commands is None else "commands", "voltages",
                               "errors") if stem != "voltages" or voltages]
    paths = [out / f"{stem}.png" for stem in stems]
    if workers is None:
        workers = min(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1, 3)
    extra = [settle_time_s] * len(stems), [commands] * len(stems)
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods():
        # forked: the workers start with matplotlib imported and its fonts loaded
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
            return list(pool.map(_write, stems, [run] * len(stems), paths, *extra))
    return [_write(stem, run, path, settle_time_s, commands) for stem, path in zip(stems, paths)]
