"""The control loop as the plant sees it in real time: missed ticks and odometry-to-command latency.

Per tick the plant publishes one odometry message; the controller answers
each with one command. The answer of tick k is the first valid command
after the odometry of tick k and before that of tick k + 1; a tick without
one is missed. Counting starts at the first answered tick (before it the
controller may still be waiting for discovery or a reference). Latencies go
into a histogram of 1 us bins (bounded memory for runs of any length).

At the end of a run the plant writes its figures as one JSON object, the
timing report (`write_report`; built by `lockstep_report` or
`realtime_report`):

``mode`` "lockstep" | "realtime"; ``ticks`` published (fresh) ticks;
``loop_ticks`` the ticks of the running loop (lockstep: 1 .. n - 1;
realtime: answered + missed); ``simulated_s`` their simulated time
(realtime: the plant time integrated); ``wall_s`` the wall time they took
(lockstep: from tick 0's answer to the last answer); ``realtime_factor``
simulated_s / wall_s (null without a loop); ``plant_busy_ms_per_tick``
time in the plant's callbacks; ``wait_ms_per_tick`` lockstep: waiting for
the command, realtime: idle; ``tick0_answer_s`` lockstep: tick 0's answer
after it went out (null in realtime); ``answered``, ``missed`` (lockstep:
every tick is answered, none missed; ``resent`` counts the resends);
``latency_ms`` realtime odometry-to-command median, p99, max (null in
lockstep or without an answer); ``first_answer_steady_s`` steady time of
the first answer; ``missed_ticks`` [[s after the first answer, s to the
next odometry], ...] (the first `MISSES_KEPT`); ``clamped_commands``,
``refused_commands`` commands clamped to the supply and refused;
``command_timeouts`` commands the drive watchdog stopped (realtime);
``windows`` (realtime with a window length, `LoopTiming.window_s`) the
same figures per consecutive window of the run: ``start_steady_s``,
``end_steady_s`` (the odometry that opened it and the one that closed
it, or the last one), ``ticks`` published in it, ``answered``,
``missed``, ``latency_ms`` (``p50``, ``p99``, ``p99.9``, ``max``; null
without an answer); the last window may be shorter.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MISSES_KEPT", "LockstepPace", "LoopTiming", "clock_minus_steady_ns", "lockstep_report", "lockstep_line",
           "realtime_report", "write_report"]

_READ_BRACKET_S = 1e-4  # a clock read taking longer than this was preempted: read again
_READ_TRIES = 5


def clock_minus_steady_ns(node: Any) -> int:
    """The node clock minus the steady clock [ns], the node clock read between two steady readings.

    Read again while the pair took over `_READ_BRACKET_S`: a preemption between two separate readings
    (another thread holding the GIL, a loaded host) put a realtime tick's stamp milliseconds off the time of
    the state it carries (single-sample spikes of a millimetre in a run's error).
    """
    for _ in range(_READ_TRIES):
        before = time.monotonic_ns()
        clock_ns = node.get_clock().now().nanoseconds
        after = time.monotonic_ns()
        if after - before <= _READ_BRACKET_S * 1e9:
            break
    return clock_ns - (before + after) // 2

MISSES_KEPT = 100  # missed ticks whose times the summary names


class LockstepPace:
    """When a lockstep plant sends its next tick: at most `factor` simulated seconds per wall second (0: no cap).

    A tick answered later than its slot goes out at once and the schedule restarts from it (no burst after a stall).
    """

    def __init__(self, factor: float, period_s: float) -> None:
        self.step_s = period_s / factor if factor > 0.0 else 0.0
        self.due = -math.inf

    def delay(self, now: float) -> float:
        """Seconds from steady time `now` [s] until the next tick may go out (0: now)."""
        self.due = max(self.due + self.step_s, now)
        return self.due - now


class LoopTiming:
    """Missed ticks and latency percentiles of a realtime loop, from the plant's steady clock.

    Parameters
    ----------
    bin_s
        Histogram bin width [s] (the resolution of the percentiles).
    max_s
        Latencies at or above this land in the last bin (percentiles there read as its upper edge;
        `max_latency_s` keeps the true largest).
    window_s
        If > 0, the figures are also kept per window of this length [s] (`windows`), a window closing at the
        first odometry at least `window_s` after the one that opened it (a soak's drift over hours).
    """

    def __init__(self, bin_s: float = 1e-6, max_s: float = 0.1, window_s: float = 0.0) -> None:
        if not 0.0 < bin_s < max_s:
            raise ValueError(f"need 0 < bin_s < max_s, got bin_s={bin_s}, max_s={max_s}")
        if not window_s >= 0.0:
            raise ValueError(f"need window_s >= 0, got {window_s}")
        self.bin_s = bin_s
        self.counts = np.zeros(int(np.ceil(max_s / bin_s)) + 1, dtype=np.int64)
        self.window_s = window_s
        self.windows: list[dict[str, Any]] = []  # the closed windows (`_window_figures`)
        self._window = _Window(len(self.counts)) if window_s > 0.0 else None
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
        window, sent = self._window, self._sent_at
        if self._waiting and self.answered and sent is not None:
            self.missed += 1
            if window is not None:
                window.missed += 1
            if len(self.missed_at) < MISSES_KEPT:
                self.missed_at.append((sent, t - sent))
        if window is not None:
            if window.start is None:
                window.start = t
            elif t - window.start >= self.window_s:
                self.windows.append(self._window_figures(window, t))
                window.reset(t)
            window.ticks += 1
        self._sent_at, self._waiting = t, True

    def command(self, t: float) -> None:
        """A valid command arrived at steady time `t` [s] (a second one in the same tick is ignored)."""
        if not self._waiting or self._sent_at is None:
            return
        self._waiting = False
        if not self.answered:
            self.first_answer_at = t
        self.answered += 1
        latency = t - self._sent_at
        self.max_latency_s = max(self.max_latency_s, latency)
        index = min(int(latency / self.bin_s), len(self.counts) - 1)
        self.counts[index] += 1
        if self._window is not None:
            self._window.add(index, latency)

    def percentile_s(self, q: float, counts: np.ndarray | None = None) -> float:
        """The `q`-th percentile (0..100) of the latencies [s] (or of the histogram `counts`), to one bin (the upper
        edge of its bin); NaN if none.
        """
        counts = self.counts if counts is None else counts
        total = int(counts.sum())
        if total == 0:
            return float("nan")
        rank = max(int(np.ceil(q / 100.0 * total)), 1)  # nearest-rank percentile
        index = int(np.searchsorted(np.cumsum(counts), rank))
        return (index + 1) * self.bin_s

    def _window_figures(self, window: _Window, end: float) -> dict[str, Any]:
        """The figures of the open `window`, ending at steady time `end` [s] (see the module docstring)."""
        latency = None
        if window.answered:
            latency = {f"p{q:g}": 1e3 * self.percentile_s(q, window.counts) for q in (50, 99, 99.9)}
            latency["max"] = 1e3 * window.max_s
        return {"start_steady_s": window.start, "end_steady_s": end, "ticks": window.ticks,
                "answered": window.answered, "missed": window.missed, "latency_ms": latency}

    def summary(self) -> str:
        """One line: ticks answered and missed, latency median, p99 and max in ms, when the first misses were.

        The misses are timed from the first answer, whose steady time the line gives too (so other
        measurements on the machine's steady clock can be set beside them).
        """
        line = (f"{self.answered} ticks answered, {self.missed} missed; odometry-to-command latency "
                f"median {1e3 * self.percentile_s(50):.3f} ms, p99 {1e3 * self.percentile_s(99):.3f} ms, "
                f"max {1e3 * self.max_latency_s:.3f} ms")
        first = self.first_answer_at
        if first is not None:
            line += f"; first answer at steady time {first:.6f} s"
            if self.missed_at:  # (a miss is counted after the first answer only)
                line += "; missed ticks (s after the first answer: ms to the next odometry) " + ", ".join(
                    f"{t - first:.6f}: {1e3 * gap:.3f}" for t, gap in self.missed_at)
        return line

    def figures(self) -> dict[str, Any]:
        """The realtime part of the timing report: answered, missed, latency_ms, first answer, missed_ticks."""
        answered, first, window = self.answered > 0, self.first_answer_at or 0.0, self._window
        return {
            "answered": self.answered,
            "missed": self.missed,
            "latency_ms": {"median": 1e3 * self.percentile_s(50), "p99": 1e3 * self.percentile_s(99),
                           "max": 1e3 * self.max_latency_s} if answered else None,
            "first_answer_steady_s": self.first_answer_at,
            "missed_ticks": [[t - first, gap] for t, gap in self.missed_at],  # (after the first answer only)
            **({} if window is None else {"windows": self.windows + (
                [self._window_figures(window, self._sent_at)] if window.ticks and self._sent_at is not None
                else [])}),
        }


class _Window:
    """The histogram and counts of one window of `LoopTiming` (reset as the next opens)."""

    def __init__(self, bins: int) -> None:
        self.counts = np.zeros(bins, dtype=np.int64)
        self.reset(None)

    def reset(self, start: float | None) -> None:
        self.counts.fill(0)
        self.start: float | None = start
        self.ticks, self.answered, self.missed, self.max_s = 0, 0, 0, 0.0

    def add(self, index: int, latency: float) -> None:
        self.counts[index] += 1
        self.answered += 1
        self.max_s = max(self.max_s, latency)


def _ratio(numerator: float, denominator: float) -> float | None:
    return numerator / denominator if denominator > 0 else None


def lockstep_report(ticks: int, period_s: float, sent_at: float, first_answer_at: float, last_answer_at: float,
                    busy_s: float, wait_s: float, **counts: int) -> dict[str, Any]:
    """The timing report of a lockstep run of `ticks` ticks (steady times [s]; busy/wait summed over 1 .. n - 1).

    `counts`: resent, clamped_commands, refused_commands, command_timeouts.
    """
    loop_ticks = ticks - 1
    simulated, wall = loop_ticks * period_s, last_answer_at - first_answer_at
    per_tick = 1e3 / loop_ticks if loop_ticks else 0.0
    return {
        "mode": "lockstep", "ticks": ticks, "loop_ticks": loop_ticks, "simulated_s": simulated, "wall_s": wall,
        "realtime_factor": _ratio(simulated, wall) if loop_ticks else None,
        "plant_busy_ms_per_tick": busy_s * per_tick, "wait_ms_per_tick": wait_s * per_tick,
        "tick0_answer_s": first_answer_at - sent_at, "answered": ticks, "missed": 0, "latency_ms": None,
        "first_answer_steady_s": first_answer_at, "missed_ticks": [], **counts,
    }


def lockstep_line(report: dict[str, Any]) -> str:
    """The human one-line summary of a lockstep report (the plant's "run over" log line)."""
    ticks, loop_ticks = report["ticks"], report["loop_ticks"]
    if not loop_ticks:
        return f"run over: {ticks} tick (no loop to time)"
    return (f"run over: {ticks} ticks; ticks 1-{loop_ticks} ({report['simulated_s']:g} s simulated) in "
            f"{report['wall_s']:.3f} s after tick 0 was answered (real-time factor {report['realtime_factor']:.1f}; "
            f"per tick {report['plant_busy_ms_per_tick']:.2f} ms in the plant, {report['wait_ms_per_tick']:.2f} ms "
            f"waiting for the command); tick 0 answered {report['tick0_answer_s']:.3f} s after it went out; "
            f"{report['resent']} resent, {report['clamped_commands']} commands clamped, "
            f"{report['refused_commands']} refused")


def realtime_report(timing: LoopTiming, ticks: int, simulated_s: float, wall_s: float, busy_s: float,
                    **counts: int) -> dict[str, Any]:
    """The timing report of a realtime run: `ticks` published over `wall_s`, `busy_s` in the plant's callbacks."""
    figures = timing.figures()
    busy_ms = 1e3 * busy_s / ticks if ticks else 0.0
    return {
        "mode": "realtime", "ticks": ticks, "loop_ticks": timing.answered + timing.missed, "simulated_s": simulated_s,
        "wall_s": wall_s, "realtime_factor": _ratio(simulated_s, wall_s), "plant_busy_ms_per_tick": busy_ms,
        "wait_ms_per_tick": 1e3 * wall_s / ticks - busy_ms if ticks else 0.0, "tick0_answer_s": None,
        **figures, **counts,
    }


def write_report(path: str | os.PathLike, report: dict[str, Any]) -> None:
    """Write `report` as one JSON object to `path`, atomically (a reader never sees half a file); OSError."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(report, allow_nan=False) + "\n")
    os.replace(tmp, path)
