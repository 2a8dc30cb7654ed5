"""`robotino-geom-mpc regress BAG`: the recorded odometry and previews through a fresh controller.

Prints the largest deviation between the recomputed and the recorded wheel
voltages; exit status 0 when it is within ``--tol`` (default 1e-12 V), 1 on
a mismatch, 2 when the recording cannot be used (see `recording.regress`).
A damaged bag is named in one warning line with what was recovered; the
verdict covers the ticks that could be read. A chain recording (the controller through the driver chain,
``chain.active``; also a real robot's, without ground truth) is replayed by `recording.regress_chain`, with the
chain's parameters of ``--chain-params``, else those the recording holds (the controller's parameter events, else
the run parameters the recorder stored), else the preset.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from . import VERBS, UsageError
from robotino_geom_mpc.cli.reindex import warn_damage

__all__ = ["add_parser", "run"]


def _tolerance(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of volts, got {text!r}") from None
    if not math.isfinite(value) or value < 0.0:
        raise argparse.ArgumentTypeError(f"must be finite and >= 0, got {text!r}")
    return value


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `regress` verb."""
    parser = sub.add_parser(
        "regress",
        help=VERBS["regress"],
        description="Feed the recorded odometry and reference previews of each control tick into a fresh "
        "controller and compare its voltages (or cmd_vel twists) with the recorded ones (exit 1 beyond --tol).",
    )
    parser.add_argument("bag", type=Path, metavar="BAG", help="bag directory or .mcap file")
    parser.add_argument("--namespace", default=None, metavar="NS",
                        help="one robot of a fleet's bag: its namespace, e.g. robot2")
    parser.add_argument("--params", type=Path, default=None,
                        help="ROS 2 parameter file (default: the parameters stored in the recording)")
    parser.add_argument("--chain-params", type=Path, default=None, metavar="FILE",
                        help="a chain recording: the controller's chain.* from this parameter file (identify's "
                        "chain_params.yaml; default: those the recording holds, else the robocup-logistics preset)")
    parser.add_argument("--tol", type=_tolerance, default=1e-12, metavar="TOL",
                        help="largest accepted deviation [V; m/s and rad/s for a cmd_vel recording] (default 1e-12)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the regression and print its verdict."""
    from robotino_geom_mpc.recording.bag_reader import BagReader, damage_report
    from robotino_geom_mpc.recording.bagfile import BagError
    from robotino_geom_mpc.recording.regress import regress_bag

    try:
        bag = BagReader(args.bag)
        warn_damage("regress", damage_report(bag))
        if args.namespace is not None:  # the robot's topics and the global ones
            bag = bag.in_namespace(args.namespace)
        result = regress_bag(bag, params_file=args.params, tolerance_v=args.tol, chain_file=args.chain_params)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    where = "" if result.worst_time_s is None else f" at t = {result.worst_time_s:.3f} s"
    verdict = "PASS" if result.passed else "FAIL"
    print(f"{verdict}: {result.compared} of {result.ticks} ticks compared, max deviation "
          f"{result.max_deviation_v:.3e} {result.unit}{where} (tolerance {result.tolerance_v:g} {result.unit})")
    if result.chain_source is not None:
        print(f"chain recording: the chain controller replayed, its parameters from {result.chain_source}")
    if result.gap_at_s is not None:
        print(f"the recording lacks the {result.gap} of the tick at t = {result.gap_at_s:.3f} s: "
              "the replay stopped there (the controller's state needs every tick)")
    return 0 if result.passed else 1
