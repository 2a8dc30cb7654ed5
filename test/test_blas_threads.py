"""BLAS on one thread where the cores are already filled: a study worker and a node, read back through
threadpoolctl's own report (`threadpool_info`) in fresh processes started with two BLAS threads.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.ros

STUDY_WORKER = """
import json
from concurrent.futures import ProcessPoolExecutor
from threadpoolctl import threadpool_info
import numpy, scipy.linalg
from robotino_geom_mpc.blas import one_blas_thread
from robotino_geom_mpc.offline import study

def blas_threads():
    import numpy, scipy.linalg  # both libraries loaded in the worker
    return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

if __name__ == "__main__":
    with ProcessPoolExecutor(1, mp_context=study._context()) as plain:
        before = plain.submit(blas_threads).result()
    with ProcessPoolExecutor(1, mp_context=study._context(), initializer=one_blas_thread) as pool:
        after = pool.submit(blas_threads).result()
    print(json.dumps([before, after]))
"""


def test_a_study_worker_runs_blas_on_one_thread(tmp_path):
    script = tmp_path / "worker.py"
    script.write_text(STUDY_WORKER)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, env=env,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    before, after = json.loads(proc.stdout)
    assert len(before) >= 2 and set(before.values()) == {2}  # numpy's and scipy's OpenBLAS, as the process started
    assert after.keys() == before.keys() and set(after.values()) == {1}
