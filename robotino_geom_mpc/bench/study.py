"""Benchmark ``study``: the aggregate real-time factor of a short Monte-Carlo study on all cores."""

from __future__ import annotations

import os
import time

from robotino_geom_mpc.bench.registry import benchmark
from robotino_geom_mpc.params.files import load_params

__all__ = ["bench_study"]


@benchmark("study", "Monte-Carlo robustness study (`study.run_study`) of paper-circle on all cores, "
           "simulated seconds per wall second of the whole study, beside the same runs one after another here")
def bench_study(quick: bool) -> dict[str, float]:
    """`study.run_study` of 8 (quick: 2) runs per core of paper-circle, 22 s each (quick: 5 s).

    The wall time counts the process pool's start and the collection of every
    row, as `robotino-geom-mpc study` does (not the figures). Its peer, measured
    right after on the same draws: the runs one after another in this process
    (`study.run_one`, one core, no pool), ``study_serial_realtime_factor``;
    ``study_speedup_vs_serial`` is the study's factor over it (at most about
    the number of cores; 600x on 2 cores needs 300x per core, 73 ms per 22 s run).
    """
    from robotino_geom_mpc.offline.study import draw_runs, run_one, run_study, summarize

    workers = os.cpu_count() or 1
    per_core, duration_s = (2, 5.0) if quick else (8, None)
    robot, control = load_params()
    draws = draw_runs(per_core * workers, 0)
    result = run_study("paper-circle", robot, control, draws, duration_s=duration_s, workers=workers,
                       progress=False)
    summary = summarize(result, "paper-circle")
    start = time.perf_counter()
    serial = [run_one("paper-circle", robot, control, draw, duration_s, 1.0) for draw in draws]
    serial_factor = sum(row["simulated_s"] for row in serial) / (time.perf_counter() - start)
    return {
        "study_aggregate_realtime_factor": summary["aggregate_realtime_factor"],
        "study_serial_realtime_factor": serial_factor,
        "study_speedup_vs_serial": summary["aggregate_realtime_factor"] / serial_factor,
        "study_runs": float(summary["runs"]),
        "study_failed_runs": float(summary["failed_runs"]),
        "study_workers": float(workers),
        "study_wall_s": summary["wall_s"],
    }
