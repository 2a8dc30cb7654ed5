"""The `robotino-geom-mpc` command: one entry point, one module per verb.

Each verb module offers `add_parser(subparsers)` and `run(args) -> int`.
Errors a user can fix (a bad parameter file, an unknown scenario, a corrupt
bag) are `UsageError` or the core's `ParamError`: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import sys
from typing import NoReturn

from robotino_geom_mpc.blas import one_blas_thread
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.params.specs import ParamError

__all__ = ["UsageError", "main", "VERBS", "positive_float", "seed_value"]

# verb -> one-line summary; the verb's module is robotino_geom_mpc.cli.<verb>, imported only when
# that verb runs, so a verb does not pay for the others' imports.
VERBS: dict[str, str] = {
    "analyze": "check the decoupling field and the functional-controllability orders",
    "simulate": "run a scenario offline (no ROS) and write metrics.json and the figures",
    "run": "run a scenario over DDS (plant, controller, trajectory, recorder as processes)",
    "report": "metrics.json and the figures of a recorded run (bag directory or .mcap)",
    "replay": "republish a recorded bag over DDS (original timing, optional /clock)",
    "regress": "recompute a recording's wheel voltages with a fresh controller and compare",
    "reindex": "make a bag usable after its recorder was killed (finalised MCAP, metadata.yaml)",
    "study": "Monte-Carlo robustness study: many offline runs with the controller's model drawn off the truth",
    "tune": "search the MPC weights and horizon over Monte-Carlo studies, with a held-out certificate",
    "bench": "time the control step against OSQP and the offline simulation",
    "identify": "fit the real robot's driver chain (dead time, ramps, speed loop) from a short cmd_vel excitation",
    "preflight": "dry run before the first motion: check the driver chain (graph, odometry rate, stamps, at rest)",
}


class UsageError(RobotinoError):
    """An error in what the user asked for; reported in one line, exit status 2."""


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (a duration in seconds, a rate factor)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be finite and > 0, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer (1 or more), got {text!r}")
    return value


def seed_value(text: str) -> int:
    """argparse type: a non-negative integer seed."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text!r}")
    return value


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # argparse exits 2 already; keep its one-line form
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser(verb: str | None = None) -> argparse.ArgumentParser:
    """The command's parser: only `verb`'s module is imported; the other verbs get their summary."""
    parser = _Parser(
        prog="robotino-geom-mpc",
        description="Geometric decoupling plus decoupled MPC for the Festo Robotino.",
    )
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    sub.required = True
    for name, summary in VERBS.items():
        if name == verb:
            importlib.import_module(f"{__name__}.{name}").add_parser(sub)
        else:
            sub.add_parser(name, help=summary)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse `argv` and run the verb; returns the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    verb = next((a for a in argv if not a.startswith("-")), None)
    os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)  # a venv install: message definitions live there
    if "OPENBLAS_NUM_THREADS" not in os.environ:  # unless the user chose: one BLAS thread here and in children
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        one_blas_thread()
    args = build_parser(verb if verb in VERBS else None).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UsageError, ParamError) as exc:
        print(f"robotino-geom-mpc {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"robotino-geom-mpc {args.verb}: interrupted", file=sys.stderr)
        return 130
