"""`blas_threads.one_blas_thread`: numpy's and scipy's OpenBLAS report one thread after it, read back through
OpenBLAS's own getters in a fresh process started with two threads.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

CODE = """
import ctypes, json
import numpy, scipy.linalg
from robotino_geom_mpc.blas_threads import one_blas_thread

def threads():
    out = {}
    for line in open("/proc/self/maps"):
        path = line.split()[-1]
        if "openblas" in path.lower() and ".so" in path and path not in out:
            lib = ctypes.CDLL(path)
            getters = [n for n in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                                   "openblas_get_num_threads64_", "openblas_get_num_threads") if hasattr(lib, n)]
            out[path] = getattr(lib, getters[0])() if getters else None
    return out

before = threads()
one_blas_thread()
print(json.dumps([before, threads()]))
"""


def test_numpy_and_scipy_openblas_on_one_thread():
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2")
    proc = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == 0, proc.stderr
    before, after = json.loads(proc.stdout)
    assert len(before) >= 2  # numpy's and scipy's bundled libraries
    assert set(before.values()) == {2}  # the getters read what the process started with
    assert set(after.values()) == {1}
