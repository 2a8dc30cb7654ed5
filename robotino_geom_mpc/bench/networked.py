"""Benchmark ``networked``: the realtime loop over DDS with plans beside the uncompensated controller.

The command's time of action is known with plans; both sides run in the same benchmark, interleaved
(`NETWORKED_RUNS` repeats, medians):

* ``wifi_compensated_rms_m``: ``run --scenario wifi --realtime`` (the plant's emulated WiFi link each way, the
  controller's delay-compensated plans), the RMS position error after settling from the bag's ground truth;
* its peer ``wifi_uncompensated_rms_m``: the same with ``--no-compensation`` (plain commands acting on arrival);
* ``local_plans_rms_m``: ``run --scenario paper-circle --realtime --plans`` on one host without a link (plans:
  each command acts at the time its plan gives, on the plant's grid);
* its peer ``local_plain_rms_m``: the same without ``--plans`` (today's loop: a command acts when it arrives);
* ``wifi_compensation_gain`` and ``local_plans_gain``: uncompensated / compensated RMS (> 1: better with plans).

The realtime figures depend on the machine keeping the loop's deadlines (a loaded 2-core machine misses ticks):
the run's missed ticks come as ``*_missed`` (the plant's timing report) so a figure can be read with them.
"""

from __future__ import annotations

import json
import statistics
import tempfile
from pathlib import Path

from robotino_geom_mpc.bench.end_to_end import run_verb
from robotino_geom_mpc.bench.registry import BenchmarkSkipped, benchmark

__all__ = ["NETWORKED_RUNS", "RUN_DURATION_S", "bench_networked", "realtime_run"]

NETWORKED_RUNS = 3  # quick: 1
RUN_DURATION_S = 12.0
_SIDES = {  # figure prefix: run arguments
    "wifi_compensated": ["--scenario", "wifi"],
    "wifi_uncompensated": ["--scenario", "wifi", "--no-compensation"],
    "local_plans": ["--scenario", "paper-circle", "--plans"],
    "local_plain": ["--scenario", "paper-circle"],
}


def realtime_run(out: Path, arguments: list[str], duration_s: float = RUN_DURATION_S) -> dict[str, float]:
    """One ``run --realtime`` with `arguments` in a subprocess: its RMS position error [m] and missed ticks."""
    from robotino_geom_mpc.system.processes import TIMING_REPORT

    run_verb(out, [*arguments, "--realtime"], duration_s)
    metrics = json.loads((out / "metrics.json").read_text())
    timing = json.loads((out / "logs" / TIMING_REPORT).read_text())
    return {"rms_m": metrics["rms_position_error_m"], "missed": timing.get("missed", 0)}


@benchmark("networked", "realtime run over the wifi link and on one host, with plans beside the uncompensated "
           "controller (RMS position error from the bag's ground truth)")
def bench_networked(quick: bool) -> dict[str, float]:
    """Medians over `NETWORKED_RUNS` interleaved repeats of each side (one with `quick`); see the module docstring."""
    try:
        import rclpy  # noqa: F401  (the nodes need it)
    except ImportError as exc:
        raise BenchmarkSkipped(f"ROS 2 not available: {exc}") from None
    samples: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="robotino_networked_") as tmp:
        for k in range(1 if quick else NETWORKED_RUNS):
            for side, arguments in _SIDES.items():
                figures = realtime_run(Path(tmp) / f"{side}{k}", arguments)
                samples.setdefault(f"{side}_rms_m", []).append(figures["rms_m"])
                samples.setdefault(f"{side}_missed", []).append(figures["missed"])
    out = {key: statistics.median(values) for key, values in samples.items()}
    out["wifi_compensation_gain"] = out["wifi_uncompensated_rms_m"] / out["wifi_compensated_rms_m"]
    out["local_plans_gain"] = out["local_plain_rms_m"] / out["local_plans_rms_m"]
    return out
