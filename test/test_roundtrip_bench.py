"""The bare rclpy round trip (`bench.roundtrip`): its statistics against stand-in samples, its report, a real run."""

import json
import os
import subprocess
import sys

import pytest

from robotino_geom_mpc.bench.registry import BenchmarkError
from robotino_geom_mpc.bench.roundtrip import bench_roundtrip, nearest_rank, read_roundtrip_report, roundtrip_figures
from robotino_geom_mpc.system.processes import NodeGroup

pytestmark = pytest.mark.ros


def test_figures_are_the_nearest_rank_median_and_p99_in_us():
    samples = [1e-6 * k for k in range(200, 0, -1)]  # 1 .. 200 us, unordered
    out = roundtrip_figures(samples)
    # nearest rank: ceil(0.5 * 200) = 100th and ceil(0.99 * 200) = 198th smallest
    assert out == {"roundtrip_us_median": pytest.approx(100.0), "roundtrip_us_p99": pytest.approx(198.0)}
    assert roundtrip_figures([3e-4]) == {"roundtrip_us_median": pytest.approx(300.0),
                                         "roundtrip_us_p99": pytest.approx(300.0)}


@pytest.mark.parametrize("n", [1, 2, 3, 7, 100, 101])
def test_nearest_rank_is_the_smallest_value_with_q_percent_at_or_below(n):
    values = list(range(n))
    for q in (1, 50, 99, 100):
        chosen = nearest_rank(values, q)
        assert sum(v <= chosen for v in values) >= q / 100 * n  # covers q percent
        assert sum(v < chosen for v in values) < q / 100 * n  # and no smaller value does
    with pytest.raises(ValueError):
        nearest_rank([], 50)


def test_the_report_must_hold_the_round_trips_asked_for(tmp_path):
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"roundtrip_s": [1e-3, 2e-3]}))
    assert read_roundtrip_report(path, 2) == [1e-3, 2e-3]
    for content in ({"roundtrip_s": [1e-3]}, {"roundtrip_s": [1e-3, -1.0]}, {"roundtrip_s": [1e-3, "x"]}, {}, [1]):
        path.write_text(json.dumps(content))
        with pytest.raises(BenchmarkError, match="round trip"):
            read_roundtrip_report(path, 2)
    path.write_text("{not json")
    with pytest.raises(BenchmarkError, match="no report"):
        read_roundtrip_report(path, 2)
    with pytest.raises(BenchmarkError, match="no report"):
        read_roundtrip_report(tmp_path / "missing.json", 2)


def test_a_failing_process_is_a_benchmark_error_and_nothing_is_left_running(monkeypatch):
    """A plant that exits at once (bad arguments): the error names it, the controller is stopped."""
    started = []
    start = NodeGroup.start

    def bad_start(group, name, args, module=None):
        node = start(group, name, ["--role", "plant", "--count", "0"] if name == "roundtrip_plant" else args, module)
        started.append(node.popen)
        return node

    monkeypatch.setattr(NodeGroup, "start", bad_start)
    with pytest.raises(BenchmarkError, match="roundtrip_plant exited with status 2"):
        bench_roundtrip(count=10, warmup=0, timeout_s=60.0)
    assert len(started) == 2 and all(p.poll() is not None for p in started)
    for popen in started:  # their process groups are gone too
        with pytest.raises(ProcessLookupError):
            os.killpg(popen.pid, 0)


def test_the_module_names_its_missing_arguments():
    proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc.bench.roundtrip", "--role", "plant"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "--report" in proc.stderr and "Traceback" not in proc.stderr
