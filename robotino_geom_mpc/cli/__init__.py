"""The `robotino-geom-mpc` command: one entry point, one module per verb.

Each verb module offers `add_parser(subparsers)` and `run(args) -> int`.
Errors a user can fix (a bad parameter file, an unknown scenario, a corrupt
bag) are `UsageError` or the core's `ParamError`: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from robotino_geom_mpc.core.params import ParamError

__all__ = ["UsageError", "main", "VERBS"]

# verb name -> module under robotino_geom_mpc.cli
VERBS: dict[str, str] = {
    "analyze": "analyze",
    "simulate": "simulate",
    "bench": "bench",
    "replay": "replay",
    "report": "report",
    "regress": "regress",
    "run": "run",
}


class UsageError(Exception):
    """An error in what the user asked for; reported in one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # argparse exits 2 already; keep its one-line form
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="robotino-geom-mpc",
        description="Geometric decoupling plus decoupled MPC for the Festo Robotino.",
    )
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    sub.required = True
    for verb, module in VERBS.items():
        importlib.import_module(f"{__name__}.{module}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse `argv` and run the verb; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UsageError, ParamError) as exc:
        print(f"robotino-geom-mpc {args.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"robotino-geom-mpc {args.verb}: interrupted", file=sys.stderr)
        return 130
