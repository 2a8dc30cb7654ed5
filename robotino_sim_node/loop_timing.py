"""The control loop as the plant sees it in real time: missed ticks and odometry-to-command latency.

Per tick the plant publishes one odometry message; the controller answers
each with one command. The answer of tick k is the first valid command
after the odometry of tick k and before that of tick k + 1; a tick without
one is missed. Counting starts at the first answered tick (before it the
controller may still be waiting for discovery or a reference). Latencies go
into a histogram of 1 us bins (bounded memory for runs of any length).
"""

from __future__ import annotations

import numpy as np

__all__ = ["MISSES_KEPT", "LoopTiming"]

MISSES_KEPT = 100  # missed ticks whose times the summary names


class LoopTiming:
    """Missed ticks and latency percentiles of a realtime loop, from the plant's steady clock.

    Parameters
    ----------
    bin_s
        Histogram bin width [s] (the resolution of the percentiles).
    max_s
        Latencies at or above this land in the last bin (percentiles there read as its upper edge;
        `max_latency_s` keeps the true largest).
    """

    def __init__(self, bin_s: float = 1e-6, max_s: float = 0.1) -> None:
        if not 0.0 < bin_s < max_s:
            raise ValueError(f"need 0 < bin_s < max_s, got bin_s={bin_s}, max_s={max_s}")
        self.bin_s = bin_s
        self.counts = np.zeros(int(np.ceil(max_s / bin_s)) + 1, dtype=np.int64)
        self.max_latency_s = 0.0
        self.answered = 0  # ticks with an answer (the first answered one included)
        self.missed = 0  # ticks after the first answered one without an answer
        self.first_answer_at: float | None = None
        # the first `MISSES_KEPT` missed ticks: (steady time of their odometry, time until the next odometry)
        self.missed_at: list[tuple[float, float]] = []
        self._sent_at: float | None = None  # steady time of the last odometry
        self._waiting = False  # the last odometry has no answer yet

    def published(self, t: float) -> None:
        """The odometry of a new tick went out at steady time `t` [s]."""
        if self._waiting and self.answered:
            self.missed += 1
            if len(self.missed_at) < MISSES_KEPT:
                self.missed_at.append((self._sent_at, t - self._sent_at))
        self._sent_at, self._waiting = t, True

    def command(self, t: float) -> None:
        """A valid command arrived at steady time `t` [s] (a second one in the same tick is ignored)."""
        if not self._waiting:
            return
        self._waiting = False
        if not self.answered:
            self.first_answer_at = t
        self.answered += 1
        latency = t - self._sent_at
        self.max_latency_s = max(self.max_latency_s, latency)
        self.counts[min(int(latency / self.bin_s), len(self.counts) - 1)] += 1

    def percentile_s(self, q: float) -> float:
        """The `q`-th percentile (0..100) of the latencies [s], to one bin (the upper edge of its bin); NaN if none."""
        total = int(self.counts.sum())
        if total == 0:
            return float("nan")
        rank = max(int(np.ceil(q / 100.0 * total)), 1)  # nearest-rank percentile
        index = int(np.searchsorted(np.cumsum(self.counts), rank))
        return (index + 1) * self.bin_s

    def summary(self) -> str:
        """One line: ticks answered and missed, latency median, p99 and max in ms, when the first misses were.

        The misses are timed from the first answer, whose steady time the line gives too (so other
        measurements on the machine's steady clock can be set beside them).
        """
        line = (f"{self.answered} ticks answered, {self.missed} missed; odometry-to-command latency "
                f"median {1e3 * self.percentile_s(50):.3f} ms, p99 {1e3 * self.percentile_s(99):.3f} ms, "
                f"max {1e3 * self.max_latency_s:.3f} ms")
        if self.first_answer_at is not None:
            line += f"; first answer at steady time {self.first_answer_at:.6f} s"
        if self.missed_at:
            line += "; missed ticks (s after the first answer: ms to the next odometry) " + ", ".join(
                f"{t - self.first_answer_at:.6f}: {1e3 * gap:.3f}" for t, gap in self.missed_at)
        return line
