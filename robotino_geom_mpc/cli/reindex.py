"""`robotino-geom-mpc reindex BAG`: a finalised MCAP and metadata.yaml for a bag whose recorder was killed.

Prints what it did: the defects found, the messages recovered per topic and
their time span, the bytes lost, where the damaged original was kept.
Exit status 0 when the bag is usable afterwards; 2 when nothing could be
done (not a bag directory, not MCAP, no readable message).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import VERBS, UsageError

__all__ = ["add_parser", "run", "warn_damage"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `reindex` verb."""
    parser = sub.add_parser(
        "reindex",
        help=VERBS["reindex"],
        description="Rebuild BAG/metadata.yaml and, if the .mcap file is damaged (no footer after SIGKILL, "
        "a corrupt chunk), a finalised .mcap from its readable chunks; the damaged file is kept as "
        "<file>.mcap.damaged. Like ros2 bag reindex.",
    )
    parser.add_argument("bag", type=Path, metavar="BAG", help="bag directory")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Reindex the bag and say what was recovered and lost."""
    from robotino_geom_mpc.recording.bagfile import BagError
    from robotino_geom_mpc.recording.reindex import reindex_bag

    try:
        result = reindex_bag(args.bag)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    if result.kept is None:
        print(f"{result.file} is intact: {result.contents}; rewrote {args.bag / 'metadata.yaml'}")
        return 0
    for problem in result.problems:
        print(f"damage: {problem}")
    print(f"recovered {result.contents}; lost {result.bytes_lost} bytes of the original")
    print(f"kept the original as {result.kept}; wrote a finalised {result.file} and {args.bag / 'metadata.yaml'}")
    return 0


def warn_damage(verb: str, report: str | None) -> None:
    """Print a damaged bag's one-line report (`recording.bag_reader.damage_report`) as the verb's warning."""
    if report is not None:
        print(f"robotino-geom-mpc {verb}: warning: {report}", file=sys.stderr)
