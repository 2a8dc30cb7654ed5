"""bench end_to_end: one `run` as a user starts it, timed; its loop's factor is the plant's own, its phases add up."""

from __future__ import annotations

import json
import re

from robotino_geom_mpc.bench import REGISTRY
from robotino_geom_mpc.bench.end_to_end import timed_run
from robotino_geom_mpc.system.processes import TIMING_REPORT


def test_timed_run_reports_the_plants_factor_and_its_phases(tmp_path):
    out = tmp_path / "run"
    figures = timed_run(out, duration_s=2.0)
    # the plant's timing report and its log line (an independent reading of the same loop) agree
    report = json.loads((out / "logs" / TIMING_REPORT).read_text())
    assert report["mode"] == "lockstep" and report["ticks"] == 200
    assert figures["lockstep_with_recorder_realtime_factor"] == report["realtime_factor"]
    log = (out / "logs" / "plant_node.err.log").read_text()
    logged = float(re.search(r"real-time factor ([\d.]+)", log)[1])
    assert abs(logged - report["realtime_factor"]) <= 0.05 + 1e-9 * logged
    # the command's wall time holds every phase it printed
    phases = figures["run_until_plant_end_s"] + figures["run_stop_s"] + figures["run_report_s"]
    assert 0.0 < phases <= figures["run_end_to_end_s"]
    # and it wrote the run's results from a recording that holds every tick
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["rms_position_error_m"] < 1e-5


def test_registered():
    assert "end_to_end" in REGISTRY
