"""Benchmark ``study``: the aggregate real-time factor of a Monte-Carlo study, batched against run by run."""

from __future__ import annotations

import os
import time

from robotino_geom_mpc.bench.registry import benchmark
from robotino_geom_mpc.params.files import load_params

__all__ = ["bench_study"]


@benchmark("study", "Monte-Carlo study (`study.run_study`) of paper-circle on all cores, simulated seconds per wall "
           "second, batched against run by run and two workers against one on the same draws, and the batched "
           "loop's CPU per run and tick beside the per-run loop's")
def bench_study(quick: bool) -> dict[str, float]:
    """1000 (quick: 64) runs of paper-circle, 22 s each (quick: 5 s), stepped together on all cores.

    The wall time counts the process pool's start and the collection of every row, as
    `robotino-geom-mpc study` does (not the figures). Its peers, measured right after on the same draws:
    a tenth of the runs run by run (``batched=False``, the per-tick float path) on the same cores,
    ``study_per_run_aggregate_realtime_factor`` and ``study_batched_speedup_vs_per_run``; a quarter of the
    runs batched on one worker against two, ``study_two_workers_speedup_vs_one``. Then, in this process (one
    core, one OpenBLAS thread, no pool), CPU time per run and tick of one task of the study (`study.run_rows`,
    half the runs stepped together, metrics included), ``batched_us_per_run_tick``, and of 4 (quick: 2) of
    the same runs run by run, ``per_run_us_per_tick``, the two alternating three times (the best of each):
    ``batched_cpu_speedup_vs_per_run``.
    """
    from robotino_geom_mpc.blas import one_blas_thread
    from robotino_geom_mpc.offline.study import batch_size, draw_runs, run_rows, run_study, summarize

    workers = os.cpu_count() or 1
    runs, duration_s, alone = (64, 5.0, 2) if quick else (1000, None, 4)
    robot, control = load_params()
    draws = draw_runs(runs, 0)

    def factor(chosen, batched=True, count=workers) -> tuple[float, dict]:
        result = run_study("paper-circle", robot, control, chosen, duration_s=duration_s, workers=count,
                           progress=False, batched=batched)
        summary = summarize(result, "paper-circle")
        return summary["aggregate_realtime_factor"], summary

    batched, summary = factor(draws)
    per_run, _ = factor(draws[: max(workers, runs // 10)], batched=False)
    quarter = draws[: max(2, runs // 4)]
    two, _ = factor(quarter, count=2)
    one, _ = factor(quarter, count=1)
    one_blas_thread()  # as in the study's workers (OpenBLAS threads only spin on these sizes)
    task = draws[: batch_size(runs, workers)]
    ticks = summary["simulated_s"] / runs / control.period_s
    cost: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(3):
        for together, chosen in ((True, task), (False, task[:alone])):
            start = time.process_time()
            run_rows("paper-circle", robot, control, chosen, duration_s, 1.0, batched=together)
            cost[together].append((time.process_time() - start) / (len(chosen) * ticks) * 1e6)
    return {
        "study_aggregate_realtime_factor": batched,
        "study_per_run_aggregate_realtime_factor": per_run,
        "study_batched_speedup_vs_per_run": batched / per_run,
        "study_two_workers_speedup_vs_one": two / one,
        "batched_us_per_run_tick": min(cost[True]),
        "per_run_us_per_tick": min(cost[False]),
        "batched_cpu_speedup_vs_per_run": min(cost[False]) / min(cost[True]),
        "study_runs": float(summary["runs"]),
        "study_failed_runs": float(summary["failed_runs"]),
        "study_workers": float(workers),
        "study_wall_s": summary["wall_s"],
    }
