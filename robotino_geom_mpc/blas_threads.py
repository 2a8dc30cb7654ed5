"""OpenBLAS on one thread in this process, for processes that fill the cores themselves.

numpy and scipy each bundle an OpenBLAS whose threads, on these matrix sizes, mostly spin; the setter is
OpenBLAS's own C function, reached through ``ctypes`` (what threadpoolctl does, without the dependency).
"""

from __future__ import annotations

import ctypes

__all__ = ["one_blas_thread"]


def one_blas_thread() -> None:
    """This process's OpenBLAS libraries (numpy's, scipy's) on one thread each.

    For processes that already fill the cores (the study's workers): OpenBLAS threads would only spin on
    the others' cores (measured: a 22 s paper-circle run's process time 1.7 times its wall time with them,
    the study's aggregate factor 1.3 times higher without). Libraries without the setter are left as they
    are, and so is every library where /proc/self/maps cannot be read.
    """
    try:
        with open("/proc/self/maps", encoding="utf-8") as maps:  # the loaded libraries (Linux)
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower() and ".so" in line}
    except OSError:
        return
    for path in sorted(paths):
        library = ctypes.CDLL(path)
        for name in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                     "openblas_set_num_threads64_", "openblas_set_num_threads"):
            setter = getattr(library, name, None)
            if setter is not None:
                setter(1)
                break
