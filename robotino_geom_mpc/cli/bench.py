"""`robotino-geom-mpc bench`: run the registered benchmarks (robotino_geom_mpc.bench).

Progress goes to stderr; a table of the figures goes to stdout, and with
--json the last line of stdout is one JSON object of all figures.
"""

from __future__ import annotations

import argparse
import json
import sys

from . import VERBS, UsageError, positive_float

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `bench` verb."""
    parser = sub.add_parser(
        "bench",
        help=VERBS["bench"],
        description="Run the benchmarks: one control step against OSQP on the same MPC problems, "
        "the offline simulation's real-time factor, the nodes over DDS beside a bare rclpy round trip, "
        "the CDR fast path against rclpy's serialization, and any further registered benchmark "
        "(the soak only with --only soak).",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object of all figures as the last line")
    parser.add_argument("--quick", action="store_true", help="fewer steps and repeats (smoke run, noisier figures)")
    parser.add_argument("--only", nargs="+", metavar="NAME", default=None, help="run only these benchmarks")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="length of the benchmarks that take one (soak: default 1800 s)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the benchmarks and print their figures; returns the exit status."""
    from robotino_geom_mpc.bench import REGISTRY, BenchmarkError, run_benchmarks

    if args.only is not None:
        unknown = [name for name in args.only if name not in REGISTRY]
        if unknown:
            raise UsageError(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(REGISTRY)}")
    if args.duration is not None and not any(REGISTRY[name].takes_duration for name in args.only or ()):
        takers = ", ".join(name for name, entry in REGISTRY.items() if entry.takes_duration)
        raise UsageError(f"--duration needs --only with a benchmark that takes one ({takers})")
    try:
        results = run_benchmarks(quick=args.quick, names=args.only, duration_s=args.duration)
    except BenchmarkError as exc:  # a failed benchmark, not a usage error
        print(f"robotino-geom-mpc bench: failed: {exc}", file=sys.stderr)
        return 1
    width = max((len(key) for key in results), default=0)
    for key, value in results.items():
        print(f"{key:<{width}}  {value:.6g}")
    if args.json:
        print(json.dumps(results, sort_keys=True))
    return 0
