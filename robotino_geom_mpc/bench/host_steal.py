"""CPU time the hypervisor took from this virtual machine ("steal" in /proc/stat), sampled over a run.

On a virtual machine the host can stop a virtual CPU to run something else;
Linux counts that time as steal (`man 5 proc`, the eighth value of the
``cpu`` line, in ``USER_HZ`` units). While the host steals both CPUs nothing
in the machine runs, so a realtime loop misses ticks whatever its code does.
`StealSampler` keeps a timeline of the machine's steal on the steady clock
(`time.monotonic`, the clock the plant's loop timing uses) so the benchmark
can tell which missed ticks fell where the host took the CPU.
"""

from __future__ import annotations

import os
import threading
import time
from bisect import bisect_left, bisect_right
from collections.abc import Callable
from pathlib import Path

__all__ = ["PROC_STAT", "StealSampler", "read_steal_s"]

PROC_STAT = Path("/proc/stat")
_STEAL_FIELD = 8  # cpu user nice system idle iowait irq softirq steal ...


def read_steal_s(path: str | os.PathLike = PROC_STAT) -> float | None:
    """The machine's steal time so far [s], summed over its CPUs; None where there is no such file (not Linux).

    Raises ValueError if the file has no well-formed aggregate ``cpu`` line.
    """
    try:
        with open(path, encoding="ascii") as f:
            first = f.readline()
    except FileNotFoundError:
        return None
    fields = first.split()
    if len(fields) <= _STEAL_FIELD or fields[0] != "cpu":
        raise ValueError(f"{path}: the first line is not the aggregate cpu line with a steal column: {first!r}")
    try:
        jiffies = int(fields[_STEAL_FIELD])
    except ValueError:
        raise ValueError(f"{path}: steal column is not an integer: {fields[_STEAL_FIELD]!r}") from None
    return jiffies / os.sysconf("SC_CLK_TCK")


class StealSampler:
    """Samples the machine's steal time every `interval_s` in a thread while used as a context manager.

    `samples` holds ``(steady time [s], steal so far [s])``, the time from `clock`; without /proc/stat it
    stays empty and `available` is False. If the file turns unreadable while sampled, sampling stops, `error`
    holds the reason and `available` turns False on exit (the samples so far are kept). `sample` takes one
    sample at once (the thread's step).
    """

    def __init__(self, interval_s: float = 0.01, path: str | os.PathLike = PROC_STAT,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not interval_s > 0.0:
            raise ValueError(f"interval_s must be > 0, got {interval_s}")
        self.interval_s = interval_s
        self.path = path
        self.clock = clock
        self.samples: list[tuple[float, float]] = []
        self.available = read_steal_s(path) is not None
        self.error: ValueError | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="steal-sampler", daemon=True)

    def __enter__(self) -> StealSampler:
        if self.available:
            self.sample()
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._thread.is_alive():
            self._stop.set()
            self._thread.join()
        if self.error is None and self.available:
            self.sample()
        self.available = self.available and self.error is None

    def sample(self) -> None:
        """Read the steal now and append it with the clock's time (nothing once `error` is set)."""
        if self.error is not None:
            return
        try:
            steal = read_steal_s(self.path)
        except ValueError as exc:
            self.error = exc
            return
        if steal is None:
            self.error = ValueError(f"{self.path} disappeared while sampled")
            return
        self.samples.append((self.clock(), steal))

    def _run(self) -> None:
        while self.error is None and not self._stop.wait(self.interval_s):
            self.sample()

    def total_s(self) -> float:
        """Steal from the first sample to the last [s] (0 without samples)."""
        return self.samples[-1][1] - self.samples[0][1] if self.samples else 0.0

    def during(self, start: float, end: float) -> float:
        """Steal between the last sample at or before `start` and the first at or after `end` [s].

        The samples bracket the window, so steal inside it is never missed (steal near it may be
        counted); outside the sampled span the window is clipped to it.
        """
        if not self.samples or end < start:
            return 0.0
        times = [t for t, _ in self.samples]
        before = max(bisect_right(times, start) - 1, 0)
        after = min(bisect_left(times, end), len(times) - 1)
        return self.samples[after][1] - self.samples[before][1]
