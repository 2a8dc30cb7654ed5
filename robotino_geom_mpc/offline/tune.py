"""MPC weights and horizon tuned for a robust objective over Monte-Carlo studies, with a held-out certificate.

Each trial of an optuna study (TPE sampler) proposes per-axis weights and a
horizon; the closed-form gain of eq. (56) depends on q/r per axis only, so a
trial draws the ratio q_a / r_a (log-uniform over `RATIO_RANGE`) and keeps
each r_a at the base parameters' value (q_a = ratio r_a): the same gains as
drawing both, with three dimensions fewer. A trial is then a study
(`study.run_study`, the batched loop, on the local cores or a Dask cluster)
of N mismatched, noisy runs whose draws are the same for every trial:

    objective  p95 over the runs of the RMS position error (to be minimised),
    constraint p99 over the runs of the peak current <= the nominal current.

Trial 0 is the base weights (the search starts from them). A trial whose
nominal closed loop is unstable (`mpc.check_closed_loop`) is pruned before
any run; so is one whose first quarter of runs already has a p95 above the
median of the earlier trials' at that stage (optuna's
MedianPruner); a trial that goes on runs the other three quarters (each run
once). The best feasible trial is then run again, with the base
weights beside it, on a held-out study (draws from another seed): the
certificate. Plain Python: no rclpy.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from robotino_geom_mpc.control.mpc import UnstableClosedLoopError, check_closed_loop
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.offline.study import draw_runs, run_study
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams

__all__ = ["RATIO_RANGE", "HORIZON_RANGE", "HELD_OUT_SEED_OFFSET", "TuneError", "StudyScore", "score_study",
           "tune"]

RATIO_RANGE = (1e5, 1e9)  # q_a / r_a per axis [1/s^4]; below ~3e5 the loop is unstable at N = 4
HORIZON_RANGE = (2, 12)
HELD_OUT_SEED_OFFSET = 1_000_003  # the certificate's draws: seed + this
AXES = ("x", "y", "theta")
TRIAL_COLUMNS = ("trial", "state", *(f"q_{a}" for a in AXES), *(f"r_{a}" for a in AXES), "horizon",
                 "p95_rms_position_error_m", "p99_peak_current_a", "feasible", "failed_runs", "wall_s")


class TuneError(RobotinoError, ValueError):
    """A bad tune setting, or no trial that keeps the current limit, named in the message."""


@dataclass(frozen=True)
class StudyScore:
    """A study's figures for the tuning: p95 RMS position error [m], p99 peak current [A], failed runs."""

    p95_rms_position_error_m: float
    p99_peak_current_a: float
    failed_runs: int


def score_study(rows: list[dict[str, Any]]) -> StudyScore:
    """The objective and constraint figures of a study's rows (numpy's linear percentiles; a failed run is +inf)."""
    rms = np.array([math.inf if row["error"] or row["rms_position_error_m"] is None else row["rms_position_error_m"]
                    for row in rows])
    peak = np.array([math.inf if row["error"] else row["peak_current_a"] for row in rows])
    failed = sum(1 for row in rows if row["error"])

    def percentile(values: np.ndarray, q: float) -> float:
        with np.errstate(invalid="ignore"):
            value = float(np.percentile(values, q))
        return math.inf if math.isnan(value) else value  # between two failed runs: inf - inf

    return StudyScore(percentile(rms, 95), percentile(peak, 99), failed)


def _control_of(base: ControlParams, params: dict[str, Any]) -> ControlParams:
    """The base settings with a trial's ratios (q_a = ratio_a r_a) and horizon."""
    q = {f"q_{a}": params[f"ratio_{a}"] * getattr(base, f"r_{a}") for a in AXES}
    return replace(base, horizon=int(params["horizon"]), **q)


def tune(
    scenario: str, robot: RobotinoParams, base: ControlParams, *, samples: int, trials: int, out: str | os.PathLike,
    seed: int = 0, duration_s: float | None = None, workers: int | None = None, scheduler: str | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Search the weights and horizon, write DIR's files and return the certificate.

    Parameters
    ----------
    scenario
        A name of `scenarios.SCENARIOS` (each run's reference and scenario mismatch).
    robot, base
        The true robot and the base controller settings (the defaults the certificate compares with).
    samples, trials
        Runs per study (N) and optuna trials (T).
    out
        DIR: trials.csv, params.yaml (the best settings, a ROS 2 parameter file), objective.png,
        certificate.json and optuna.db (the optuna storage: ``optuna-dashboard sqlite:///DIR/optuna.db``).
    seed
        Seed of the tuning draws; the certificate's are seed + `HELD_OUT_SEED_OFFSET`.
    duration_s, workers, scheduler, progress
        As for `study.run_study` (``progress``: one bar over the trials).

    Returns
    -------
    dict
        The certificate (certificate.json): per side (``tuned``, ``default``) its weights, horizon and
        held-out figures, ``nominal_current_a``, and ``passed`` (tuned p95 <= default's and tuned p99 peak
        current <= nominal).

    Raises
    ------
    TuneError
        For fewer than 1 sample or trial, or when no trial kept the p99 peak current within nominal.
    """
    import optuna

    from robotino_geom_mpc.params.files import write_parameter_file

    if samples < 1 or trials < 1:
        raise TuneError(f"samples and trials must be >= 1, got {samples} and {trials}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    nominal = robot.nominal_current_a
    draws = draw_runs(samples, seed)
    stage = max(1, samples // 4)

    def rows_of(control: ControlParams, chosen: list) -> list[dict[str, Any]]:
        return run_study(scenario, robot, control, chosen, duration_s=duration_s, workers=workers,
                         scheduler=scheduler, progress=False).rows

    def study(control: ControlParams, chosen: list) -> StudyScore:
        return score_study(rows_of(control, chosen))

    def objective(trial: optuna.Trial) -> float:
        params = {f"ratio_{a}": trial.suggest_float(f"ratio_{a}", *RATIO_RANGE, log=True) for a in AXES}
        params["horizon"] = trial.suggest_int("horizon", *HORIZON_RANGE)
        control = _control_of(base, params)
        trial.set_user_attr("control", {f: getattr(control, f) for f in ("q_x", "q_y", "q_theta", "r_x", "r_y",
                                                                        "r_theta", "horizon")})
        try:
            check_closed_loop(robot, control)
        except UnstableClosedLoopError:
            raise optuna.TrialPruned() from None
        start = time.perf_counter()
        rows = rows_of(control, draws[:stage])
        if stage < samples:  # the first quarter's figure, then the other runs (each run once)
            trial.report(score_study(rows).p95_rms_position_error_m, 0)
            if trial.should_prune():
                raise optuna.TrialPruned()
            rows += rows_of(control, draws[stage:])
        score = score_study(rows)
        trial.set_constraint("p99_peak_current_over_nominal_a", score.p99_peak_current_a - nominal)
        trial.set_user_attr("p99_peak_current_a", score.p99_peak_current_a)
        trial.set_user_attr("failed_runs", score.failed_runs)
        trial.set_user_attr("wall_s", time.perf_counter() - start)
        return score.p95_rms_position_error_m

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = f"sqlite:///{(out / 'optuna.db').resolve()}"
    search = optuna.create_study(
        study_name=f"tune-{scenario}-{seed}-{samples}", storage=storage, load_if_exists=False, direction="minimize",
        sampler=optuna.samplers.TPESampler(seed=seed),
        pruner=optuna.pruners.MedianPruner(n_startup_trials=5, n_warmup_steps=0))
    # the base weights are trial 0: the search starts from them, so its best is no worse on the tuning draws
    search.enqueue_trial({**{f"ratio_{a}": float(np.clip(getattr(base, f"q_{a}") / getattr(base, f"r_{a}"),
                                                          *RATIO_RANGE)) for a in AXES},
                          "horizon": int(np.clip(base.horizon, *HORIZON_RANGE))})
    with tqdm(total=trials, desc=f"tune {scenario}", unit="trial", disable=not progress) as bar:
        def advance(study: optuna.Study, trial: optuna.trial.FrozenTrial) -> None:
            bar.update(1)
            best = _best(study, nominal)
            if best is not None:
                bar.set_postfix(best_p95_rms_mm=f"{best.value * 1e3:.4g}")

        search.optimize(objective, n_trials=trials, callbacks=[advance])
    _write_trials(out / "trials.csv", search, nominal)
    best = _best(search, nominal)
    if best is None:
        raise TuneError(f"no trial kept the p99 peak current within nominal ({nominal:g} A); see {out / 'trials.csv'}")
    tuned = _control_of(base, best.params)
    params_path = write_parameter_file(
        out / "params.yaml", robot, tuned,
        f"robotino-geom-mpc tune --scenario {scenario} --samples {samples} --trials {trials} --seed {seed}:\n"
        f"trial {best.number}, p95 RMS position error {best.value:.6g} m over the tuning study")
    _plot(out / "objective.png", search, nominal)
    held_out = draw_runs(samples, seed + HELD_OUT_SEED_OFFSET)
    sides = {}
    for name, control in (("tuned", tuned), ("default", base)):
        score = study(control, held_out)
        sides[name] = {"q": list(control.q), "r": list(control.r), "horizon": control.horizon, **asdict(score)}
    certificate = {
        "scenario": scenario, "samples": samples, "trials": trials, "seed": seed,
        "held_out_seed": seed + HELD_OUT_SEED_OFFSET, "nominal_current_a": nominal, **sides,
        "passed": bool(sides["tuned"]["p95_rms_position_error_m"] <= sides["default"]["p95_rms_position_error_m"]
                       and sides["tuned"]["p99_peak_current_a"] <= nominal),
        "params_file": params_path.name,
    }
    (out / "certificate.json").write_text(json.dumps(certificate, indent=2) + "\n", encoding="utf-8")
    return certificate


def _feasible(trial: Any, nominal: float) -> bool:
    return trial.value is not None and trial.user_attrs.get("p99_peak_current_a", math.inf) <= nominal


def _best(study: Any, nominal: float) -> Any:
    """The completed trial with the lowest objective among those that keep the current constraint, or None."""
    import optuna

    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE and _feasible(t, nominal)]
    return min(done, key=lambda t: t.value) if done else None


def _write_trials(path: Path, study: Any, nominal: float) -> None:
    with open(path, "w", newline="", encoding="utf-8") as stream:
        writer = csv.DictWriter(stream, fieldnames=TRIAL_COLUMNS)
        writer.writeheader()
        for t in study.trials:
            control = t.user_attrs.get("control", {})
            writer.writerow({
                "trial": t.number, "state": t.state.name, **{k: control.get(k, "") for k in TRIAL_COLUMNS[2:9]},
                "p95_rms_position_error_m": "" if t.value is None else t.value,
                "p99_peak_current_a": t.user_attrs.get("p99_peak_current_a", ""),
                "feasible": _feasible(t, nominal), "failed_runs": t.user_attrs.get("failed_runs", ""),
                "wall_s": t.user_attrs.get("wall_s", ""),
            })


def _plot(path: Path, study: Any, nominal: float) -> None:
    """The objective of each completed trial (feasible or not) and the best feasible one so far."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4))
    done = [t for t in study.trials if t.value is not None]
    for feasible, style, label in ((True, "o", "feasible (p99 peak current <= nominal)"),
                                   (False, "x", "p99 peak current above nominal")):
        chosen = [t for t in done if _feasible(t, nominal) == feasible]
        axis.plot([t.number for t in chosen], [t.value * 1e3 for t in chosen], style, label=label)
    best, line = math.inf, []
    for t in study.trials:
        if t.value is not None and _feasible(t, nominal):
            best = min(best, t.value)
        line.append(best * 1e3 if math.isfinite(best) else np.nan)
    axis.step(range(len(line)), line, where="post", label="best feasible so far")
    axis.set_xlabel("trial")
    axis.set_ylabel("p95 RMS position error [mm]")
    axis.set_yscale("log")
    axis.legend()
    axis.grid(True, alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
