"""Benchmark ``end_to_end``: the main job as a user starts it, ``robotino-geom-mpc run`` from the command to its exit.

Side by side in one pass, repeats interleaved (`END_TO_END_RUNS`, medians):

* ``run_end_to_end_s``: ``robotino-geom-mpc run --scenario paper-circle
  --duration 20`` (lockstep, recorded) in a subprocess, from the start of
  the process to its exit, after it wrote metrics.json and the figures;
* ``lockstep_with_recorder_realtime_factor``: that run's loop, from the
  plant's timing report (``DIR/logs/plant_timing.json``, the one `run`
  asks the plant for): ticks 1 .. n - 1 with the recorder subscribed;
* its peer ``lockstep_without_recorder_realtime_factor``: the same loop
  without a recorder (`dds.bench_lockstep`);
* the floor ``rclpy_import_s``: ``python -c 'import rclpy'``, the start of
  one bare ROS 2 Python process (a run starts four or more at once).

The run's own phases (printed by `run`: until the plant ended, stopping
the nodes and closing the recording, metrics and figures) come as
``run_until_plant_end_s``, ``run_stop_s`` and ``run_report_s``.
"""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from robotino_geom_mpc.bench.registry import BenchmarkError, BenchmarkSkipped, benchmark

__all__ = ["END_TO_END_RUNS", "RUN_DURATION_S", "bench_end_to_end", "run_command", "run_verb", "timed_run"]

END_TO_END_RUNS = 3  # quick: 1
RUN_DURATION_S = 20.0
TIMEOUT_S = 600.0
_PHASES = re.compile(r"run in [\d.]+ s wall: ([\d.]+) s until the plant ended .*?, ([\d.]+) s to stop")
_REPORT = re.compile(r"the figures in ([\d.]+) s")


def run_command() -> list[str]:
    """``robotino-geom-mpc`` as installed beside this interpreter (the console script), else ``python -m``."""
    script = Path(sys.executable).with_name("robotino-geom-mpc")
    return [str(script)] if script.exists() else [sys.executable, "-m", "robotino_geom_mpc"]


def run_verb(out: Path, arguments: list[str], duration_s: float) -> str:
    """``robotino-geom-mpc run ARGUMENTS --duration D --out OUT`` in a subprocess; its standard output.

    Raises
    ------
    BenchmarkError
        If the run fails, takes over `TIMEOUT_S` or writes no metrics.json.
    """
    command = [*run_command(), "run", *arguments, "--duration", f"{duration_s:g}", "--out", str(out)]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise BenchmarkError(f"`{' '.join(command)}` did not end within {TIMEOUT_S:g} s") from None
    if done.returncode != 0 or not (out / "metrics.json").is_file():
        raise BenchmarkError(f"`{' '.join(command)}` failed (status {done.returncode}):\n{done.stderr[-2000:]}")
    return done.stdout


def timed_run(out: Path, scenario: str = "paper-circle", duration_s: float = RUN_DURATION_S) -> dict[str, float]:
    """One ``run`` in a subprocess: its wall time, its loop's real-time factor and its printed phases.

    Raises
    ------
    BenchmarkError
        If the run fails, times out, writes no metrics.json or its plant no timing report.
    """
    from robotino_geom_mpc.bench.dds import read_timing_report
    from robotino_geom_mpc.system.processes import TIMING_REPORT

    start = time.perf_counter()
    stdout = run_verb(out, ["--scenario", scenario], duration_s)
    wall = time.perf_counter() - start
    loop = read_timing_report(out / "logs" / TIMING_REPORT, "lockstep")
    if loop["realtime_factor"] is None:
        raise BenchmarkError(f"the run in {out} had no loop to time ({loop['ticks']} ticks)")
    figures = {"run_end_to_end_s": wall, "lockstep_with_recorder_realtime_factor": loop["realtime_factor"]}
    phases, report = _PHASES.search(stdout), _REPORT.search(stdout)
    if phases and report:
        figures.update(run_until_plant_end_s=float(phases[1]), run_stop_s=float(phases[2]),
                       run_report_s=float(report[1]))
    return figures


def _rclpy_import_s() -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import rclpy"], check=True, stdin=subprocess.DEVNULL)
    return time.perf_counter() - start


@benchmark("end_to_end", "`run --scenario paper-circle --duration 20` as a user starts it, beside the loop "
           "without the recorder and a bare rclpy process start")
def bench_end_to_end(quick: bool) -> dict[str, float]:
    """Medians over `END_TO_END_RUNS` interleaved repeats of each side (one with `quick`); see the module docstring."""
    try:
        import rclpy  # noqa: F401  (the nodes need it)

        from robotino_geom_mpc.bench.dds import bench_lockstep
    except ImportError as exc:
        raise BenchmarkSkipped(f"ROS 2 not available: {exc}") from None
    samples: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="robotino_end_to_end_") as tmp:
        for k in range(1 if quick else END_TO_END_RUNS):
            figures = timed_run(Path(tmp) / f"run{k}")
            figures["lockstep_without_recorder_realtime_factor"] = bench_lockstep(
                duration_s=RUN_DURATION_S)["lockstep_dds_realtime_factor"]
            figures["rclpy_import_s"] = _rclpy_import_s()
            for key, value in figures.items():
                samples.setdefault(key, []).append(value)
    out = {key: statistics.median(values) for key, values in samples.items()}
    out["run_end_to_end_s_min"] = min(samples["run_end_to_end_s"])
    out["run_end_to_end_s_max"] = max(samples["run_end_to_end_s"])
    return out
