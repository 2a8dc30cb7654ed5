"""`robotino-geom-mpc tune`: MPC weights and horizon for a robust objective, with a held-out certificate.

`offline.tune.tune` runs an optuna search whose every trial is a Monte-Carlo
study (the batched loop, on all cores or a Dask cluster) and writes DIR's
trials.csv, params.yaml (a ROS 2 parameter file for ``run --params`` and the
nodes), objective.png and certificate.json.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import VERBS, UsageError, positive_float, positive_int, seed_value
from robotino_geom_mpc.cli.simulate import add_scenario_argument

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `tune` verb."""
    parser = sub.add_parser(
        "tune", help=VERBS["tune"],
        description="Search the per-axis MPC weights (q/r) and the horizon with optuna (TPE, median pruning) "
        "for the lowest 95th percentile of the RMS position error over a study of N mismatched, noisy runs, "
        "subject to the 99th percentile of the peak current staying at or below nominal; then compare the best "
        "with the parameter file's weights on a held-out study (other seeds): the certificate.",
    )
    add_scenario_argument(parser)
    parser.add_argument("--samples", type=positive_int, required=True, metavar="N", help="runs per study")
    parser.add_argument("--trials", type=positive_int, required=True, metavar="T", help="optuna trials")
    parser.add_argument("--seed", type=seed_value, default=0, metavar="S",
                        help="seed of the tuning draws and the sampler (default 0); the certificate's draws use "
                        "another seed")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="Dask scheduler address for the trials' studies (default: the local cores)")
    parser.add_argument("--workers", type=positive_int, default=None, metavar="K",
                        help="local processes (default: the number of cores)")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="simulated time of each run [s] (default: the scenario's length)")
    parser.add_argument("--params", type=Path, default=None,
                        help="ROS 2 parameter file of the true robot and the base weights (default: Robotino 3 preset)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Tune, write DIR, print the certificate's line; exit status 0 when the certificate passes, 1 when not."""
    try:
        import optuna  # noqa: F401
    except ImportError:
        raise UsageError("tune needs optuna: pip install 'robotino_geom_mpc[tune]'") from None
    from robotino_geom_mpc.offline.tune import tune
    from robotino_geom_mpc.params.files import load_params

    robot, control = load_params(args.params)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create output folder {args.out}: {exc.strerror or exc}") from None
    if (args.out / "optuna.db").exists():
        raise UsageError(f"{args.out} already holds a tuning (optuna.db); choose another --out")
    c = tune(args.scenario, robot, control, samples=args.samples, trials=args.trials, out=args.out, seed=args.seed,
             duration_s=args.duration, workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress)
    tuned, default = c["tuned"], c["default"]
    print(f"tune {args.scenario}: certificate {'PASSED' if c['passed'] else 'FAILED'} on {c['samples']} held-out "
          f"runs: p95 RMS position error {tuned['p95_rms_position_error_m'] * 1e3:.4g} mm tuned vs "
          f"{default['p95_rms_position_error_m'] * 1e3:.4g} mm default, p99 peak current "
          f"{tuned['p99_peak_current_a']:.3g} A tuned vs {default['p99_peak_current_a']:.3g} A default "
          f"(nominal {c['nominal_current_a']:g} A)")
    print(f"  wrote {args.out / 'params.yaml'} (run --params), trials.csv, objective.png, certificate.json")
    return 0 if c["passed"] else 1
