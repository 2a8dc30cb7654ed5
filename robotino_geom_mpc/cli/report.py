"""`robotino-geom-mpc report BAG [--out DIR]`: metrics.json and the figures of a recorded run.

The same keys and figures as ``simulate`` and ``run`` (`recording.report.write_report`, which ``run`` also calls).
A recording without ``ground_truth/odom`` (a real robot's) is reported as odometry sees it, and says so (a printed
line, ``"truth"`` in metrics.json). The run parameters come from the recording, or from ``--params``. The output
folder defaults to ``<BAG>-report`` beside the bag (``simulate`` too writes to a folder of its own by default).
A damaged bag (e.g. its recorder was killed) is named in one warning line with what was recovered; the report
covers that (exit 0).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from . import VERBS, UsageError
from robotino_geom_mpc.cli.reindex import warn_damage
from robotino_geom_mpc.cli.simulate import add_no_plots_argument

__all__ = ["add_parser", "default_out", "run", "summary"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `report` verb."""
    parser = sub.add_parser(
        "report",
        help=VERBS["report"],
        description="Extract the run (pose, reference, currents or commands, voltages per control tick) from a "
        "recording and write DIR/metrics.json and the figures, as simulate and run do. Without ground truth "
        "(a real robot's recording) the pose is the odometry's, and the report says so.",
    )
    parser.add_argument("bag", type=Path, metavar="BAG", help="bag directory or .mcap file")
    parser.add_argument("--namespace", default=None, metavar="NS",
                        help="one robot of a fleet's bag: its namespace, e.g. robot2")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="output folder (default: BAG-report beside the bag)")
    parser.add_argument("--params", type=Path, default=None,
                        help="ROS 2 parameter file (default: the parameters stored in the recording)")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")
    add_no_plots_argument(parser)
    parser.set_defaults(func=run)
    return parser


def default_out(bag: Path) -> Path:
    """The report's folder for `bag` without ``--out``: ``<bag>-report`` beside it (a .mcap file: its stem's)."""
    bag = Path(bag)
    name = bag.stem if bag.suffix == ".mcap" else bag.name
    return bag.parent / f"{name}-report"


def _figure(value: Any, unit: str) -> str:
    return "n/a" if value is None else f"{value:.3g} {unit}"


def summary(metrics: dict[str, Any], figures: list[Path], out: Path) -> list[str]:
    """The lines `report` prints: the truth used, the key metrics, the link's and chain's timing, the files."""
    truth = metrics["truth"]
    lines = [f"truth: {truth}" + ("" if truth == "ground_truth" else
                                  " (no ground_truth/odom in the recording: the tracking error as odometry sees it)"),
             f"{metrics['samples']} ticks over {metrics['duration_s']:.3g} s; position error after settle: rms "
             f"{_figure(metrics['rms_position_error_m'], 'm')}, max {_figure(metrics['max_position_error_m'], 'm')}; "
             f"peak current {_figure(metrics['peak_current_a'], 'A')}, peak voltage "
             f"{_figure(metrics['peak_voltage_v'], 'V')}"]
    if metrics.get("timing") is not None:
        from robotino_geom_mpc.recording.odometry_timing import timing_line

        lines.append(f"timing: {timing_line(metrics['timing'])}")
    if metrics.get("link") is not None:
        from robotino_geom_mpc.recording.link_report import link_line

        lines.append(f"link: {link_line(metrics['link'])}")
    lines.append(f"wrote {out / 'metrics.json'}")
    lines += [f"wrote {path}" for path in figures]
    return lines


def run(args: argparse.Namespace) -> int:
    """Write the report; a bag that cannot be read or lacks a run's topics is a UsageError.

    A damaged bag is reported in one warning line (what was recovered); the report covers what was read.
    """
    from robotino_geom_mpc.recording.bag_reader import BagReader, damage_report
    from robotino_geom_mpc.recording.bagfile import BagError
    from robotino_geom_mpc.recording.report import write_report

    out = args.out if args.out is not None else default_out(args.bag)
    try:
        bag = BagReader(args.bag)
        warn_damage("report", damage_report(bag))
        if args.namespace is not None:  # the robot's topics and the global ones
            bag = bag.in_namespace(args.namespace)
        report = write_report(bag, out, params_file=args.params, plots=not args.no_plots)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(json.dumps(report.metrics, indent=2, sort_keys=True))
    else:
        print("\n".join(summary(report.metrics, report.figures, out)))
    return 0
