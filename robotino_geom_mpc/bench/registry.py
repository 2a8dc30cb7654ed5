"""The benchmark registry: each benchmark is one function ``fn(quick) -> {figure: value}`` registered by name.

A benchmark that cannot run on this machine (e.g. no ROS) raises
`BenchmarkSkipped`. Timings use `time.perf_counter` and report medians over
interleaved repeats, so a benchmark and its peer see the same machine.
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.system.processes import NodeFailed, NodeGroup, NodeProcess

__all__ = ["Benchmark", "BenchmarkError", "BenchmarkSkipped", "REGISTRY", "benchmark", "median_per_call",
           "run_benchmarks", "wait_for_run"]


class BenchmarkError(RobotinoError, RuntimeError):
    """A benchmark whose two sides disagree or whose result is not a positive finite number."""


class BenchmarkSkipped(RobotinoError):
    """Raised by a benchmark that cannot run here; the message says why."""


@dataclass(frozen=True)
class Benchmark:
    """A registered benchmark: its name, a one-line description and the function.

    `default`: run by a plain ``bench`` (else only when named); `takes_duration`: ``func(quick, duration_s=S)``
    gets the ``--duration`` of ``bench``.
    """

    name: str
    description: str
    func: Callable[..., dict[str, float]]
    default: bool = True
    takes_duration: bool = False


REGISTRY: dict[str, Benchmark] = {}


def benchmark(name: str, description: str, default: bool = True,
              takes_duration: bool = False) -> Callable[[Callable[..., dict[str, float]]], Callable]:
    """Decorator registering ``fn(quick) -> {key: value}`` under `name` (run in registration order).

    `default` False: not run by a plain ``bench``, only by name (a soak); `takes_duration`: ``fn(quick,
    duration_s=None)`` takes ``bench --duration``.
    """

    def register(func: Callable[..., dict[str, float]]) -> Callable[..., dict[str, float]]:
        if name in REGISTRY:
            raise ValueError(f"benchmark {name!r} registered twice")
        REGISTRY[name] = Benchmark(name, description, func, default, takes_duration)
        return func

    return register


def median_per_call(passes: Sequence[Callable[[], object]], calls: int, repeats: int) -> list[float]:
    """Median wall time per call [s] of each pass (`calls` calls each), repeats interleaved."""
    samples: list[list[float]] = [[] for _ in passes]
    for _ in range(repeats):
        for run_once, store in zip(passes, samples):
            start = time.perf_counter()
            run_once()
            store.append((time.perf_counter() - start) / calls)
    return [statistics.median(store) for store in samples]


def wait_for_run(group: NodeGroup, process: NodeProcess, timeout_s: float, what: str) -> None:
    """Wait until `process` of `group` exits; `BenchmarkError` if a process of the group fails or `timeout_s` passes.

    `what` names the run in the message (e.g. "lockstep run of 22 s").
    """
    try:
        ended = group.wait(process, timeout_s)
    except NodeFailed as exc:
        raise BenchmarkError(f"{what}: {exc}") from None
    if not ended:
        raise BenchmarkError(f"{what} did not end within {timeout_s} s:\n{process.stderr_tail()}")


def run_benchmarks(
    quick: bool = False, names: list[str] | None = None, log: Callable[[str], None] | None = None,
    duration_s: float | None = None,
) -> dict[str, float]:
    """Run the registered benchmarks (all, or `names`) and merge their figures into one dict.

    Parameters
    ----------
    quick
        Fewer steps and repeats (a smoke run; figures are noisier).
    names
        Benchmarks to run; when None, those registered with ``default`` (all but the soak), in registry order.
    log
        Receives one progress line per benchmark (default: stderr).
    duration_s
        The length of the benchmarks that take one (``takes_duration``: the soak); None: their default.

    Raises
    ------
    BenchmarkError
        If a name is unknown, a benchmark's sides disagree, or a figure is
        not a positive finite number.
    """
    log = log or (lambda line: print(line, file=sys.stderr, flush=True))
    selected = [n for n, entry in REGISTRY.items() if entry.default] if names is None else list(names)
    unknown = [n for n in selected if n not in REGISTRY]
    if unknown:
        raise BenchmarkError(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(REGISTRY)}")
    results: dict[str, float] = {}
    for name in selected:
        entry = REGISTRY[name]
        log(f"bench {name}: {entry.description} ...")
        try:
            figures = entry.func(quick, duration_s=duration_s) if entry.takes_duration else entry.func(quick)
        except BenchmarkSkipped as exc:
            log(f"bench {name}: skipped ({exc})")
            continue
        for key, value in figures.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise BenchmarkError(f"benchmark {name} returned {key} = {value!r}, not a finite number >= 0")
            results[key] = float(value)
    return results
