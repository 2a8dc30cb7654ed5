"""`study --scheduler`: a study on a real Dask cluster (a `dask scheduler` and `dask worker` processes on localhost).

The truth is the same study on the local cores (`run_study` without a
scheduler): its rows, wall times aside, must come back bit for bit, every
run exactly once, from two workers and after a worker is killed mid-study
(Dask runs the dead worker's batches again on the other one).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from robotino_geom_mpc.offline import study
from robotino_geom_mpc.offline.study import StudyError, draw_runs, run_study
from robotino_geom_mpc.params.files import load_params

pytest.importorskip("dask.distributed", reason="the cluster extra: pip install '.[cluster]'")
pytestmark = [pytest.mark.ros, pytest.mark.slow]

DASK = str(Path(sys.executable).with_name("dask"))
SAMPLES, SEED, DURATION_S = 16, 5, 1.0  # 2 batches of 8 runs
STOP_GRACE_S = 3.0  # a dask process ends within a second of SIGTERM; a worker's close can hang (10 s and more)


def _without_wall(rows):
    return [{key: value for key, value in row.items() if key != "wall_s"} for row in rows]


class Cluster:
    """A `dask scheduler` on a random localhost port and its `dask worker` processes (one thread, no nanny)."""

    def __init__(self, folder: Path) -> None:
        self.file = folder / "scheduler.json"
        self.processes: list[subprocess.Popen] = []
        self.scheduler = self._start([DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                      "--scheduler-file", str(self.file)], folder / "scheduler.log")
        deadline = time.monotonic() + 120.0
        while not self.file.exists() and time.monotonic() < deadline:
            assert self.scheduler.poll() is None, (folder / "scheduler.log").read_text()
            time.sleep(0.2)
        self.address = json.loads(self.file.read_text())["address"]
        self.folder = folder

    def _start(self, argv: list[str], log: Path) -> subprocess.Popen:
        process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=open(log, "w"), start_new_session=True)
        self.processes.append(process)
        return process

    def add_worker(self, name: str) -> subprocess.Popen:
        return self._start([DASK, "worker", self.address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                            "--host", "127.0.0.1", "--name", name], self.folder / f"{name}.log")

    def wait_for_workers(self, count: int) -> None:
        from dask.distributed import Client

        with Client(self.address, timeout=60) as client:
            client.wait_for_workers(count, timeout=180)

    def stop(self) -> None:
        for process in reversed(self.processes):
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)
        for process in self.processes:
            try:
                process.wait(timeout=STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


@pytest.fixture()
def cluster(tmp_path):
    cluster = Cluster(tmp_path)
    try:
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture(scope="module")
def local():
    robot, control = load_params()
    draws = draw_runs(SAMPLES, SEED)
    rows = run_study("robustness", robot, control, draws, duration_s=DURATION_S, workers=2, progress=False).rows
    return robot, control, draws, rows


def test_two_workers_give_the_local_rows(cluster, local):
    robot, control, draws, expected = local
    workers = [cluster.add_worker("w1"), cluster.add_worker("w2")]
    cluster.wait_for_workers(2)
    result = run_study("robustness", robot, control, draws, duration_s=DURATION_S, scheduler=cluster.address,
                       progress=False)
    assert _without_wall(result.rows) == _without_wall(expected)
    assert all(row["error"] == "" for row in result.rows)
    assert all(worker.poll() is None for worker in workers)  # both lived through it
    one = run_study("robustness", robot, control, draws, duration_s=DURATION_S, workers=1, progress=False)
    assert _without_wall(one.rows) == _without_wall(expected)  # one local worker: the same rows


def test_a_worker_killed_mid_study_loses_no_run(cluster, local):
    from dask.distributed import Client

    robot, control, draws, expected = local
    victim = cluster.add_worker("victim")
    cluster.add_worker("survivor")
    cluster.wait_for_workers(2)
    outcome: dict = {}

    def study() -> None:
        try:
            outcome["result"] = run_study("robustness", robot, control, draws, duration_s=DURATION_S,
                                          scheduler=cluster.address, progress=False)
        except BaseException as exc:  # noqa: BLE001  (handed to the test's thread)
            outcome["error"] = exc

    thread = threading.Thread(target=study)
    thread.start()
    with Client(cluster.address, timeout=60) as watcher:  # kill the victim while it holds a batch
        deadline = time.monotonic() + 300.0
        while time.monotonic() < deadline:
            busy = [w for w, keys in watcher.processing().items()
                    if keys and watcher.scheduler_info()["workers"][w]["name"] == "victim"]
            if busy:
                break
            time.sleep(0.05)
        else:
            pytest.fail("the victim worker never got a batch")
        os.killpg(victim.pid, signal.SIGKILL)
    thread.join(timeout=600)
    assert not thread.is_alive()
    assert "error" not in outcome, outcome.get("error")
    rows = outcome["result"].rows
    assert [row["index"] for row in rows] == list(range(SAMPLES))  # every run exactly once
    assert _without_wall(rows) == _without_wall(expected)
    assert victim.poll() is not None


def test_an_unreachable_scheduler_is_a_clear_error(local, monkeypatch):
    robot, control, draws, _ = local
    monkeypatch.setattr(study, "SCHEDULER_TIMEOUT_S", 2.0)  # the error, not the wait, is under test
    with pytest.raises(StudyError, match="Dask scheduler"):
        run_study("robustness", robot, control, draws[:1], duration_s=DURATION_S, scheduler="tcp://127.0.0.1:9",
                  progress=False)
