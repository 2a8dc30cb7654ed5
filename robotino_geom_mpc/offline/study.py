"""Monte-Carlo robustness study: many offline closed-loop runs with the controller's model drawn off the truth.

Each run is `simulation.run_scenario` with

* the plant on the true robot (the parameter file's),
* the controller on ``truth.scaled(mass, inertia, friction)`` (on top of the
  scenario's own mismatch, if any: `Scenario.controller_model` scales that
  model again), the factors drawn uniformly from ``MASS_RANGE`` and
  ``INERTIA_RANGE`` (+-20 %) and log-uniformly from ``FRICTION_RANGE``
  (x0.5 .. x2, so halving and doubling are equally likely),
* odometry noise (position [m], heading [rad]) drawn uniformly from
  0 .. ``NOISE_MAX``, and its own noise seed,
* the odometry model drawn with equal odds from the allowed ones
  (`robotino_geom_mpc.model.encoders.ODOMETRY_MODELS`: the true pose plus the
  noise, or dead reckoning from 2048-count wheel encoders plus the noise).

`draw_runs` makes the draws from one seed (same seed, same draws), `run_study`
cuts them into batches and runs each batch as one task: by default stepped
together (`batch_simulation.batch_metrics`, each run equal to its own
`run_scenario`), or run by run (``batched=False``). The tasks go to the local
cores (`concurrent.futures.ProcessPoolExecutor`, forked after the imports) or,
with ``scheduler``, to a Dask cluster (`dask.distributed`; the ``cluster``
extra): a batch whose worker dies is run again elsewhere, and each batch's
rows are taken once, from the one future that holds them. The batches and
their runs depend on the draws only, so the rows are the same whatever runs
them (wall times aside). A run that raises becomes a row with its error instead
of ending the study. `summarize` gives the study's figures and `write_study`
writes DIR/runs.csv, DIR/summary.json and the figures (`study_plots`). Plain
Python and numpy: no rclpy.
"""

from __future__ import annotations

import csv
import hashlib
import json
import multiprocessing
import os
import pickle
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from robotino_geom_mpc.blas import one_blas_thread
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.model.encoders import ODOMETRY_MODELS
from robotino_geom_mpc.offline.batch_simulation import RunSetting, batch_metrics
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.scenarios import get_scenario

__all__ = [
    "MASS_RANGE", "INERTIA_RANGE", "FRICTION_RANGE", "NOISE_MAX", "METRICS", "STATISTICS",
    "COLUMNS", "DRAW_FIELDS", "StudyError", "Draw", "StudyResult", "draw_runs", "run_draw", "run_one",
    "run_rows", "batch_size", "run_study", "summarize", "write_study", "read_rows",
]

MASS_RANGE = (0.8, 1.2)  # controller's mass over the truth
INERTIA_RANGE = (0.8, 1.2)  # controller's yaw inertia over the truth
FRICTION_RANGE = (0.5, 2.0)  # controller's body friction over the truth (log-uniform)
NOISE_MAX = (2e-3, 2e-3)  # odometry noise std: position [m], heading [rad]
METRICS = (  # the keys of `results.compute_metrics` a row keeps
    "rms_position_error_m", "max_position_error_m", "rms_theta_error_rad", "max_abs_theta_error_rad",
    "final_position_error_m", "peak_current_a", "peak_current_after_settle_a", "samples_above_nominal_current",
    "peak_voltage_v", "saturated_steps", "infeasible_steps", "rms_position_error_odom_m", "odometry_drift_max_m",
)
STATISTICS = ("rms_position_error_m", "peak_current_a")  # summarised as median, p95, worst
BATCH_MAX = 16  # runs per pool task at most, run by run
BATCHED_MAX = 1000  # runs per task at most, stepped together (about 0.5 GB with a 22 s scenario's series)
SCHEDULER_TIMEOUT_S = 20.0  # how long `run_study` tries to reach a Dask scheduler


class StudyError(RobotinoError, ValueError):
    """A bad study setting (sample count, worker count), named in the message."""


@dataclass(frozen=True)
class Draw:
    """One run's draws.

    Attributes
    ----------
    index
        The run's number, 0 .. samples - 1 (its row).
    seed
        Seed of the run's odometry noise.
    mass, inertia, friction
        Factors of the controller's model over the true robot (`RobotinoParams.scaled`).
    noise_position_m, noise_yaw_rad
        Odometry noise standard deviations.
    odometry
        The odometry model, a name of `robotino_geom_mpc.model.encoders.ODOMETRY_MODELS`.
    """

    index: int
    seed: int
    mass: float
    inertia: float
    friction: float
    noise_position_m: float
    noise_yaw_rad: float
    odometry: str


DRAW_FIELDS = tuple(f.name for f in fields(Draw))
COLUMNS = (*DRAW_FIELDS, "simulated_s", "wall_s", *METRICS, "error")  # runs.csv, in this order


@dataclass(frozen=True)
class StudyResult:
    """The rows of a study (one dict per run, in draw order, keys `COLUMNS`) and its wall time [s]."""

    rows: list[dict[str, Any]]
    wall_s: float


def draw_runs(samples: int, seed: int, odometry: tuple[str, ...] = ODOMETRY_MODELS) -> list[Draw]:
    """`samples` draws from a generator seeded with `seed` (same arguments, same draws).

    `odometry` lists the odometry models to draw from, with equal odds.

    Raises
    ------
    StudyError
        If `samples` < 1, `seed` < 0, or `odometry` is empty or names an unknown model.
    """
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise StudyError(f"samples must be a positive integer, got {samples!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise StudyError(f"seed must be a non-negative integer, got {seed!r}")
    if not odometry or any(model not in ODOMETRY_MODELS for model in odometry):
        raise StudyError(f"odometry must name models of {', '.join(ODOMETRY_MODELS)}, got {odometry!r}")
    rng = np.random.default_rng(seed)
    mass = rng.uniform(*MASS_RANGE, samples)
    inertia = rng.uniform(*INERTIA_RANGE, samples)
    low, high = np.log(FRICTION_RANGE)
    friction = np.exp(rng.uniform(low, high, samples))
    noise = rng.uniform(0.0, 1.0, (samples, 2)) * np.array(NOISE_MAX)
    seeds = rng.integers(0, 2**31, samples)
    models = rng.integers(0, len(odometry), samples)
    return [
        Draw(k, int(seeds[k]), float(mass[k]), float(inertia[k]), float(friction[k]),
             float(noise[k, 0]), float(noise[k, 1]), odometry[models[k]])
        for k in range(samples)
    ]


def run_draw(
    scenario: str, robot: RobotinoParams, control: ControlParams, draw: Draw, duration_s: float | None,
    network: dict[str, Any] | None = None,
) -> Any:
    """`simulation.run_scenario` of one draw: the plant on `robot`, the controller on its scaled copy.

    `network` holds run_scenario's ``link_up``, ``link_down`` and ``compensate`` (None: the scenario's link).
    Returns the `results.RunData`; raises what `run_scenario` raises.
    """
    return run_scenario(RunConfig(
        scenario, robot.scaled(mass=draw.mass, inertia=draw.inertia, friction=draw.friction), control,
        duration_s=duration_s, seed=draw.seed, plant_robot=robot,
        odometry_noise=(draw.noise_position_m, draw.noise_yaw_rad), odometry=draw.odometry, **(network or {}),
    ))


def run_one(
    scenario: str, robot: RobotinoParams, control: ControlParams, draw: Draw, duration_s: float | None,
    settle_time_s: float, network: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The row of one draw: its draws, simulated and wall seconds, `METRICS`, and ``error``.

    A run that raises gives a row with ``error`` = ``"<ExceptionType>: <message>"``,
    zero simulated seconds and None metrics; a run that does not has ``error`` = "".
    """
    row: dict[str, Any] = {**asdict(draw), "simulated_s": 0.0, **dict.fromkeys(METRICS), "error": ""}
    start = time.perf_counter()
    try:
        data = run_draw(scenario, robot, control, draw, duration_s, network)
        metrics = compute_metrics(data, settle_time_s=settle_time_s)
    except Exception as exc:  # noqa: BLE001  (any failure of one run is that run's row, never the study's end)
        row["error"] = f"{type(exc).__name__}: {exc}"
    else:
        row["simulated_s"] = data.n * data.control_period_s
        row.update({key: metrics.get(key) for key in METRICS})
    row["wall_s"] = time.perf_counter() - start
    return {key: row[key] for key in COLUMNS}


def _setting(robot: RobotinoParams, draw: Draw) -> RunSetting:
    """The `batch_simulation.RunSetting` of a draw: the arguments `run_draw` gives `run_scenario`."""
    return RunSetting(robot.scaled(mass=draw.mass, inertia=draw.inertia, friction=draw.friction), robot, draw.seed,
                      (draw.noise_position_m, draw.noise_yaw_rad), draw.odometry)


def run_rows(
    scenario: str, robot: RobotinoParams, control: ControlParams, draws: list[Draw], duration_s: float | None,
    settle_time_s: float, batched: bool = True, network: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """The rows of some draws (one task of `run_study`): stepped together, or `run_one` of each.

    Stepped together, each row's ``wall_s`` is its share of the batch's wall time; a batch that raises
    (one bad run fails the batch) is run again run by run, so that only the bad runs get an error. Runs over
    a link (`network`) go run by run: the batched loop has no link.
    """
    one_blas_thread()  # a task's process shares the cores with the other tasks' (a Dask worker's too)
    if not batched or network:
        return [run_one(scenario, robot, control, draw, duration_s, settle_time_s, network) for draw in draws]
    start = time.perf_counter()
    try:
        metrics = batch_metrics(scenario, control, [_setting(robot, draw) for draw in draws], duration_s=duration_s,
                                settle_time_s=settle_time_s)
    except Exception:  # noqa: BLE001  (the per-run path names each failing run)
        return run_rows(scenario, robot, control, draws, duration_s, settle_time_s, batched=False)
    share = (time.perf_counter() - start) / len(draws)
    simulated = metrics[0]["samples"] * control.period_s
    return [{**asdict(draw), "simulated_s": simulated, "wall_s": share, **{key: m.get(key) for key in METRICS},
             "error": ""} for draw, m in zip(draws, metrics)]


def batch_size(runs: int, workers: int, batched: bool = True) -> int:
    """Runs per task.

    Stepped together: half the runs (the per-tick cost is paid once a batch, so batches are large: one per
    worker of a 2-core machine), at most `BATCHED_MAX`, whatever the workers, so that the batches (and so
    every row, to the last bit) are the same on any number of workers or machines. Run by run: at least 8
    tasks a worker so the last ones balance, at most `BATCH_MAX`.
    """
    if batched:
        return max(1, min(BATCHED_MAX, -(-runs // 2)))
    return max(1, min(BATCH_MAX, runs // (8 * workers)))


def _context() -> multiprocessing.context.BaseContext:
    """Fork where there is fork: the workers start with this process's imports done (numpy, scipy, the package)."""
    return multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else None)


def _local_rows(tasks: list[tuple], workers: int, bar: tqdm) -> list[dict[str, Any]]:
    """The tasks' rows from a pool of `workers` forked processes."""
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=workers, mp_context=_context()) as pool:
        for future in as_completed([pool.submit(run_rows, *task) for task in tasks]):
            batch = future.result()
            rows += batch
            bar.update(len(batch))
    return rows


def _cluster_rows(tasks: list[tuple], scheduler: str, bar: tqdm) -> list[dict[str, Any]]:
    """The tasks' rows from the Dask cluster at `scheduler` (tasks of dead workers are rerun by Dask)."""
    try:
        from dask.distributed import Client
        from dask.distributed import as_completed as completed
    except ImportError:
        raise StudyError("--scheduler needs dask.distributed: pip install 'robotino_geom_mpc[cluster]'") from None
    rows: list[dict[str, Any]] = []
    try:
        client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise StudyError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    with client:
        # one key per batch, from its content: a rerun after a worker's death is the same task
        futures = [client.submit(run_rows, *task, key=f"study-{hashlib.sha1(pickle.dumps(task)).hexdigest()}")
                   for task in tasks]
        for future in completed(futures):
            batch = future.result()
            rows += batch
            bar.update(len(batch))
    return rows


def run_study(
    scenario: str,
    robot: RobotinoParams,
    control: ControlParams,
    draws: list[Draw],
    *,
    duration_s: float | None = None,
    workers: int | None = None,
    settle_time_s: float = 1.0,
    progress: bool = True,
    batched: bool = True,
    scheduler: str | None = None,
    network: dict[str, Any] | None = None,
) -> StudyResult:
    """Run every draw, in batches, on `workers` local processes or on a Dask cluster.

    Parameters
    ----------
    scenario
        A name of `scenarios.SCENARIOS`.
    robot
        The true robot (the plant of every run).
    control
        The controller settings of every run.
    draws
        The runs (`draw_runs`, or any list of `Draw`).
    duration_s
        Simulated time of each run; the scenario's if None.
    workers
        Local processes; ``os.cpu_count()`` if None (the batch sizes follow it; with a scheduler, the
        cluster's workers run the batches).
    settle_time_s
        Passed to `results.compute_metrics`.
    progress
        Show a tqdm progress bar on stderr.
    batched
        Step each batch's runs together (`batch_simulation.batch_metrics`); False: one after another (`run_one`).
    scheduler
        Address of a Dask scheduler (e.g. ``tcp://10.0.0.5:8786``); None: the local cores.
    network
        ``link_up``, ``link_down``, ``compensate`` of every run (`simulation.run_scenario`); None: the scenario's.

    Returns
    -------
    StudyResult
        The rows in draw order and the wall time from the start to the last row.

    Raises
    ------
    StudyError
        No draws, `workers` < 1, or an unreachable scheduler.
    scenarios.ScenarioError
        Unknown scenario (before any run starts).
    """
    get_scenario(scenario)
    if not draws:
        raise StudyError("a study needs at least one draw")
    workers = (os.cpu_count() or 1) if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise StudyError(f"workers must be a positive integer, got {workers!r}")
    workers = min(workers, len(draws))
    batched = batched and not network  # the batched loop has no link: runs over one go run by run
    size = batch_size(len(draws), workers, batched)
    tasks = [(scenario, robot, control, draws[k : k + size], duration_s, settle_time_s, batched, network)
             for k in range(0, len(draws), size)]
    start = time.perf_counter()
    with tqdm(total=len(draws), desc=f"study {scenario}", unit="run", disable=not progress, mininterval=0.5) as bar:
        rows = _local_rows(tasks, workers, bar) if scheduler is None else _cluster_rows(tasks, scheduler, bar)
    wall_s = time.perf_counter() - start
    rows.sort(key=lambda row: row["index"])
    return StudyResult(rows, wall_s)


def summarize(result: StudyResult, scenario: str) -> dict[str, Any]:
    """The study's figures (summary.json).

    Returns
    -------
    dict
        ``scenario``, ``runs``, ``failed_runs``, ``wall_s``, ``simulated_s`` (sum over
        the runs), ``aggregate_realtime_factor`` (simulated over wall seconds of the
        whole study), for each key of `STATISTICS` its ``median``, ``p95`` (numpy's
        linear percentile) and ``worst`` (largest) over the runs without error (None if
        none), and ``worst_runs``: per key of `STATISTICS` the draws of the run with
        the largest value (None if no run succeeded). ``nominal_current_a`` is added
        by `write_study`.
    """
    ok = [row for row in result.rows if not row["error"]]
    simulated = float(sum(row["simulated_s"] for row in result.rows))
    summary: dict[str, Any] = {
        "scenario": scenario,
        "runs": len(result.rows),
        "failed_runs": len(result.rows) - len(ok),
        "wall_s": result.wall_s,
        "simulated_s": simulated,
        "aggregate_realtime_factor": simulated / result.wall_s,
        "worst_runs": {},
    }
    for key in STATISTICS:
        measured = [row for row in ok if row[key] is not None]  # None: a run shorter than the settle time
        values = np.array([row[key] for row in measured], dtype=float)
        summary[key] = None if not measured else {
            "median": float(np.median(values)),
            "p95": float(np.percentile(values, 95)),
            "worst": float(values.max()),
        }
        worst = measured[int(np.argmax(values))] if measured else None
        summary["worst_runs"][key] = None if worst is None else {f: worst[f] for f in DRAW_FIELDS}
    return summary


def write_study(
    out: str | os.PathLike, scenario: str, robot: RobotinoParams, control: ControlParams, result: StudyResult,
    *, duration_s: float | None = None, settle_time_s: float = 1.0,
) -> dict[str, Any]:
    """Write DIR/runs.csv (`COLUMNS`, one row per run), DIR/summary.json and the figures.

    The figures (`study_plots.write_study_plots`): histograms, each metric of
    `STATISTICS` against each drawn factor, and `plots.write_plots` of the worst
    run of each (rerun in this process from its draws) in ``DIR/worst_<metric>/``.

    Returns
    -------
    dict
        The summary (`summarize`, plus ``nominal_current_a`` and ``figures``, the
        written PNGs relative to DIR).
    """
    from robotino_geom_mpc.offline.plots import write_plots
    from robotino_geom_mpc.offline.study_plots import write_study_plots

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "runs.csv", "w", newline="", encoding="utf-8") as stream:
        writer = csv.DictWriter(stream, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows({k: "" if v is None else v for k, v in row.items()} for row in result.rows)
    summary = summarize(result, scenario)
    summary["nominal_current_a"] = robot.nominal_current_a
    figures = write_study_plots(result.rows, out, robot.nominal_current_a)
    for key, draws in summary["worst_runs"].items():
        if draws is not None:
            data = run_draw(scenario, robot, control, Draw(**draws), duration_s)
            figures += write_plots(data, out / f"worst_{key}", settle_time_s=settle_time_s)
    summary["figures"] = [str(path.relative_to(out)) for path in figures]
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return summary


def read_rows(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of a runs.csv: numbers as float (``index``, ``seed`` as int), empty cells as None, text as text."""
    rows = []
    with open(path, newline="", encoding="utf-8") as stream:
        for raw in csv.DictReader(stream):
            row: dict[str, Any] = {}
            for key, text in raw.items():
                if key in ("error", "odometry"):
                    row[key] = text
                elif text == "":
                    row[key] = None
                else:
                    row[key] = int(text) if key in ("index", "seed") else float(text)
            rows.append(row)
    return rows
