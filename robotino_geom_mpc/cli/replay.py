"""`robotino-geom-mpc replay BAG`: republish a recording over DDS with its original timing.

Exit status: 0 after a complete replay; 1 when the bag is damaged (one
warning line says so and what was recovered; everything readable is still replayed);
2 when nothing can be read (not a bag, not MCAP, no readable message) or an
option is wrong; 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import VERBS, UsageError, positive_float
from robotino_geom_mpc.cli.reindex import warn_damage

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `replay` verb."""
    parser = sub.add_parser(
        "replay",
        help=VERBS["replay"],
        description="Republish the messages of a bag (rosbag2 directory or bare .mcap) with their recorded "
        "timing scaled by --rate. A damaged bag (truncated, corrupt chunk) is reported and what can be read "
        "is replayed (exit status 1).",
    )
    parser.add_argument("bag", type=Path, metavar="BAG", help="bag directory or .mcap file")
    parser.add_argument("--rate", type=positive_float, default=1.0, help="playback speed factor (default 1)")
    parser.add_argument("--loop", action="store_true", help="start over at the end (until --duration or Ctrl-C)")
    parser.add_argument("--topics", nargs="+", default=None, metavar="TOPIC", help="only these topics")
    parser.add_argument("--clock", action="store_true",
                        help="publish /clock from the recorded time (for use_sim_time consumers)")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="stop after S seconds of playback (default: at the end of the bag)")
    parser.add_argument("--delay", type=float, default=1.0, metavar="S",
                        help="wait S seconds after creating the publishers, for discovery (default 1)")
    parser.add_argument("--wait-for-subscribers", action="store_true",
                        help="before the delay, wait until every replayed topic has a subscriber (at most 60 s)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Open the bag, replay it from a node named ``replay``; see the module docstring for the exit status."""
    import rclpy

    from robotino_geom_mpc.recording.bag_reader import BagReader, damage_report
    from robotino_geom_mpc.recording.bagfile import BagError
    from robotino_geom_mpc.recording.replay import replay_bag

    try:
        bag = BagReader(args.bag)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    warn_damage("replay", damage_report(bag))
    topics = None
    if args.topics:
        topics = ["/" + t.lstrip("/") for t in args.topics]
    rclpy.init()
    try:
        node = rclpy.create_node("replay")
        try:
            result = replay_bag(node, bag, rate=args.rate, loop=args.loop, topics=topics, clock=args.clock,
                                duration_s=args.duration, delay_s=args.delay,
                                wait_for_subscribers=args.wait_for_subscribers)
        except BagError as exc:
            raise UsageError(str(exc)) from None
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    print(f"replayed {result.total} messages on {len(result.published)} topics ({result.passes} full passes)")
    return 1 if bag.problems else 0
