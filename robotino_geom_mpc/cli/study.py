"""`robotino-geom-mpc study`: a Monte-Carlo robustness study of the offline closed loop.

Draws the controller's model off the truth and the odometry noise
(`study.draw_runs`), runs the draws in batches stepped together on all cores or
on a Dask cluster (`study.run_study`) and
writes DIR/runs.csv, DIR/summary.json and the figures (`study.write_study`).
A run that fails is a row with its error; the study goes on.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from . import VERBS, UsageError, positive_float, positive_int, seed_value
from robotino_geom_mpc.cli.simulate import SETTLE_TIME_S, add_chain_argument, add_link_arguments, \
    add_scenario_argument, chain_from_args, link_from_args

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `study` verb."""
    parser = sub.add_parser(
        "study",
        help=VERBS["study"],
        description="Monte-Carlo runs of a scenario in the offline closed loop with the controller's model "
        "drawn off the true robot (mass and yaw inertia +-20 %%, body friction x0.5-x2), odometry noise up to "
        "2 mm / 2 mrad, ideal or encoder odometry and random noise seeds, on all cores. "
        "Writes DIR/runs.csv (draws and metrics, one row "
        "per run), DIR/summary.json and the figures.",
    )
    add_scenario_argument(parser)
    parser.add_argument("--samples", type=positive_int, required=True, metavar="N", help="number of runs")
    parser.add_argument("--workers", type=positive_int, default=None, metavar="K",
                        help="processes (default: the number of cores)")
    parser.add_argument("--seed", type=seed_value, default=0, metavar="S", help="seed of the draws (default 0)")
    parser.add_argument("--odometry", choices=("both", "ideal", "encoders"), default="both",
                        help="odometry model of the runs: ideal (true pose plus noise), encoders (dead reckoning "
                        "from the wheel encoders plus noise) or both, drawn with equal odds (default both)")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="simulated time of each run [s] (default: the scenario's length)")
    parser.add_argument("--params", type=Path, default=None, help="ROS 2 parameter file of the true robot "
                        "(default: Robotino 3 preset)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="address of a Dask scheduler (e.g. tcp://10.0.0.5:8786) to run the batches on its "
                        "workers (the cluster extra); default: the local cores")
    parser.add_argument("--per-run", action="store_true",
                        help="run each draw on its own (the per-tick float path) instead of stepping each batch's "
                        "runs together (the same rows to 1e-9, about ten times slower)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_link_arguments(parser, "study")
    add_chain_argument(parser)
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the study, write its outputs, print the summary; returns the exit status."""
    from robotino_geom_mpc.model.encoders import ODOMETRY_MODELS

    from robotino_geom_mpc.params.files import load_params
    from robotino_geom_mpc.offline.study import draw_runs, run_study, write_study

    chain = chain_from_args(args)
    if chain is not None and args.odometry != "ideal":
        raise UsageError("--chain gives the firmware's odometry: use it with --odometry ideal")
    robot, control = load_params(args.params)
    link = link_from_args(args)
    network: dict[str, Any] | None = ({"link_up": link, "link_down": link, "compensate": not args.no_compensation}
               if link is not None or args.no_compensation else None)
    if chain is not None:
        if network is not None:
            raise UsageError("--chain has its own link (chain.link.*, set by --chain-set), not --link-* or "
                             "--no-compensation")
        network = {"command_interface": "cmd_vel", "chain": chain}
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create output folder {args.out}: {exc.strerror or exc}") from None
    draws = draw_runs(args.samples, args.seed, ODOMETRY_MODELS if args.odometry == "both" else (args.odometry,))
    result = run_study(args.scenario, robot, control, draws, duration_s=args.duration, workers=args.workers,
                       settle_time_s=SETTLE_TIME_S, progress=not args.no_progress, batched=not args.per_run,
                       scheduler=args.scheduler, network=network)
    s = write_study(args.out, args.scenario, robot, control, result, duration_s=args.duration,
                    settle_time_s=SETTLE_TIME_S)
    print(f"study {args.scenario}: {s['runs']} runs ({s['failed_runs']} failed), {s['simulated_s']:.4g} s "
          f"simulated in {s['wall_s']:.3g} s: aggregate real-time factor {s['aggregate_realtime_factor']:.4g}")
    for key, unit in (("rms_position_error_m", "m"), ("peak_current_a", "A")):
        if s[key] is not None:
            print(f"  {key}: median {s[key]['median']:.3g} {unit}, p95 {s[key]['p95']:.3g} {unit}, "
                  f"worst {s[key]['worst']:.3g} {unit}")
    print(f"  wrote {args.out / 'runs.csv'}, {args.out / 'summary.json'} and {len(s['figures'])} figures")
    return 0
