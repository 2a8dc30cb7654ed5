"""Benchmark ``study``: the aggregate real-time factor of a short Monte-Carlo study on all cores."""

from __future__ import annotations

import os

from robotino_geom_mpc.bench.registry import benchmark
from robotino_geom_mpc.core.params import load_params

__all__ = ["bench_study"]


@benchmark("study", "Monte-Carlo robustness study (`study.run_study`) of paper-circle on all cores, "
           "simulated seconds per wall second of the whole study")
def bench_study(quick: bool) -> dict[str, float]:
    """`study.run_study` of 4 (quick: 2) runs per core of paper-circle, 22 s each (quick: 5 s).

    The wall time counts the process pool's start and the collection of every
    row, as `robotino-geom-mpc study` does (not the figures); the peer figure is
    `offline_sim_realtime_factor`, one run in this process.
    """
    from robotino_geom_mpc.study import draw_runs, run_study, summarize

    workers = os.cpu_count() or 1
    per_core, duration_s = (2, 5.0) if quick else (4, None)
    robot, control = load_params()
    result = run_study("paper-circle", robot, control, draw_runs(per_core * workers, 0), duration_s=duration_s,
                       workers=workers, progress=False)
    summary = summarize(result, "paper-circle")
    return {
        "study_aggregate_realtime_factor": summary["aggregate_realtime_factor"],
        "study_runs": float(summary["runs"]),
        "study_failed_runs": float(summary["failed_runs"]),
        "study_workers": float(workers),
        "study_wall_s": summary["wall_s"],
    }
