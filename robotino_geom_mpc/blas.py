"""BLAS on one thread a process: the loop's matrices are small and the processes themselves fill the cores."""

from __future__ import annotations

__all__ = ["one_blas_thread"]


def one_blas_thread() -> None:
    """Limit this process's BLAS libraries to one thread (threadpoolctl); without threadpoolctl, nothing changes.

    A node steps 3x3 to 15x15 matrices, on which OpenBLAS threads only spin; a study's (or a Dask worker's)
    process shares the cores with the other workers'. The command line sets it too (and ``OPENBLAS_NUM_THREADS=1``
    for its children) unless the user set that variable: on a loaded 2-core host a 3x3 `scipy.linalg.expm`
    (the plant's step over an interval off the grid) took 4.7 ms on OpenBLAS's threads, 0.5 ms on one.
    threadpoolctl has no rosdep key: a node installed without it runs as it is.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(limits=1, user_api="blas")
