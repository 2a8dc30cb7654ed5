"""`robotino-geom-mpc report BAG --out DIR`: metrics.json and the figures of a recorded run.

The same keys and figures as ``simulate`` and ``run`` (`recording.report.report_bag`,
which ``run`` also calls). The run parameters come from the recording, or
from ``--params``. A damaged bag (e.g. its recorder was killed) is named in
one warning line with what was recovered; the report covers that (exit 0).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import VERBS, UsageError
from robotino_geom_mpc.cli.reindex import warn_damage
from robotino_geom_mpc.cli.simulate import add_no_plots_argument

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `report` verb."""
    parser = sub.add_parser(
        "report",
        help=VERBS["report"],
        description="Extract the run (true pose, reference, currents, voltages per control tick) from a "
        "recording and write DIR/metrics.json and the figures, as simulate and run do.",
    )
    parser.add_argument("bag", type=Path, metavar="BAG", help="bag directory or .mcap file")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    parser.add_argument("--params", type=Path, default=None,
                        help="ROS 2 parameter file (default: the parameters stored in the recording)")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")
    add_no_plots_argument(parser)
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Write the report; a bag that cannot be read or lacks a run's topics is a UsageError.

    A damaged bag is reported in one warning line (what was recovered); the report covers what was read.
    """
    from robotino_geom_mpc.recording.bag_reader import BagReader, damage_report
    from robotino_geom_mpc.recording.bagfile import BagError
    from robotino_geom_mpc.recording.report import report_bag

    try:
        bag = BagReader(args.bag)
        warn_damage("report", damage_report(bag))
        metrics = report_bag(bag, args.out, params_file=args.params, plots=not args.no_plots)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(json.dumps(metrics, indent=2, sort_keys=True))
    else:
        print(f"{metrics['samples']} ticks; metrics{'' if args.no_plots else ' and figures'} in {args.out}")
        if metrics.get("link") is not None:
            from robotino_geom_mpc.recording.link_report import link_line

            print(f"link: {link_line(metrics['link'])}")
    return 0
