"""When was an odometry message measured? Its time from the firmware's fixed rate and the driver's arrival pattern.

Behind the robocup-logistics driver (`model.driver_chain`) an odometry stamp is not a measurement time: the
firmware samples on a fixed grid g_n = t_0 + n P (P = 1 / odometry_rate_hz) and sends no stamp; the sample
reaches the driver after the up link's delay d_up plus a jitter in [0, J], and the driver stamps it with its
loop's time s when it dispatches it, at the first pass after its arrival. The previous pass was at s - T
(T = 1 / driver_rate_hz), so

    s - T - d_up - J  <  g_n  <=  s - d_up.                                            (1)

`MeasurementClock` keeps the set of grid offsets t_0 consistent with (1) for every message so far (an interval
[lo, hi], intersected message by message), and gives each message the grid point in its window (1) after the
previous message's, at the middle of that interval: the measurement time with its uncertainty (hi - lo) / 2.
With a 30 Hz driver and 50 Hz odometry the pattern of (1) repeats every 100 ms and the interval shrinks to T / 5
= 6.7 ms (+-3.3 ms) without jitter; a jitter J loosens the lower bounds by J (+-5 ms measured with J = 10 ms). A
message that would leave no consistent offset (a lost message under the wrong grid point, a clock that drifts)
restarts the interval from its own window. When two grid points fit a message's window (a lost sample before
it), `choose` (a callable on the candidate times, e.g. the pose the controller predicts at each) picks one;
without it, the earlier one, or the later with ``newest`` (a driver that dispatches only the newest sample).
d_up is the identified round trip's share of the up link (`round_trip_s` / 2 by default: the two directions of a
WiFi link are alike); an error e there shifts every time by e.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["MeasurementClock", "MeasurementClockError", "MeasurementTime"]


class MeasurementClockError(RobotinoError, ValueError):
    """A bad setting or a stamp that is not finite or goes back in time."""


class MeasurementTime(NamedTuple):
    """A reconstructed measurement time [s] (host clock), its half-uncertainty [s] and grid index."""

    time_s: float
    uncertainty_s: float
    grid_index: int


class MeasurementClock:
    """Measurement times of unstamped fixed-rate odometry, stamped on dispatch (module docstring).

    Parameters
    ----------
    odometry_period_s
        P, the firmware's odometry period [s].
    driver_period_s
        T, the driver loop's period [s].
    up_delay_s
        d_up, the fixed delay of the robot -> driver link [s].
    up_jitter_s
        J, its largest jitter [s].
    newest
        The driver dispatches only the newest sample of a pass (``chain.odometry_dispatch`` latest).
    """

    def __init__(self, odometry_period_s: float, driver_period_s: float, up_delay_s: float = 0.0,
                 up_jitter_s: float = 0.0, newest: bool = False) -> None:
        values = (odometry_period_s, driver_period_s, up_delay_s, up_jitter_s)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values) or min(values[:2]) <= 0.0 \
                or min(values[2:]) < 0.0:
            raise MeasurementClockError(f"periods must be > 0 and delays >= 0, got {values!r}")
        self.P, self.T, self.d_up, self.J = (float(v) for v in values)
        self.newest = bool(newest)
        self.reset()

    def reset(self) -> None:
        """Forget the grid (the next message starts it)."""
        self.lo = self.hi = math.nan
        self.index = -1
        self.last_stamp_s = -math.inf
        self.restarts = 0

    def _window(self, stamp_s: float) -> tuple[float, float]:
        return stamp_s - self.T - self.d_up - self.J, stamp_s - self.d_up

    def update(self, stamp_s: float, choose: Callable[[Sequence[float]], int] | None = None) -> MeasurementTime:
        """The measurement time of the message stamped `stamp_s` (messages in dispatch order)."""
        if not math.isfinite(stamp_s) or stamp_s < self.last_stamp_s:
            raise MeasurementClockError(f"stamp {stamp_s!r} s is not finite or before the previous one")
        self.last_stamp_s = stamp_s
        low, high = self._window(stamp_s)
        if self.index < 0:
            self.lo, self.hi, self.index = low, high, 0
            return self._time()
        # grid points after the previous message's whose offset range meets the window (1)
        first = max(self.index + 1, math.floor((low - self.hi) / self.P) + 1)
        candidates = [n for n in range(first, math.ceil((high - self.lo) / self.P) + 1)
                      if self.lo + n * self.P < high + 1e-12 and self.hi + n * self.P > low - 1e-12]
        if not candidates:
            return self._restart(stamp_s, low, high)
        mid = 0.5 * (self.lo + self.hi)
        pick = max([i for i, n in enumerate(candidates) if mid + n * self.P <= high] or [0]) if self.newest else 0
        if len(candidates) > 1 and choose is not None:
            pick = int(choose([mid + n * self.P for n in candidates]))
            if not 0 <= pick < len(candidates):
                raise MeasurementClockError(f"choose returned {pick}, not an index of {len(candidates)} candidates")
        n = candidates[pick]
        lo, hi = max(self.lo, low - n * self.P), min(self.hi, high - n * self.P)
        if lo > hi + 1e-12:
            return self._restart(stamp_s, low, high)
        self.lo, self.hi, self.index = lo, hi, n
        return self._time()

    def _restart(self, stamp_s: float, low: float, high: float) -> MeasurementTime:
        """No offset fits: a grid of this message's window alone, continuing the numbering."""
        self.restarts += 1
        n = self.index + max(1, round((0.5 * (low + high) - 0.5 * (self.lo + self.hi)) / self.P - self.index))
        self.lo, self.hi, self.index = low - n * self.P, high - n * self.P, n
        return self._time()

    def _time(self) -> MeasurementTime:
        mid = 0.5 * (self.lo + self.hi)
        return MeasurementTime(mid + self.index * self.P, 0.5 * (self.hi - self.lo), self.index)

    def tick_time(self, index: int) -> float:
        """The (middle estimate of the) time of grid point `index` [s]."""
        return 0.5 * (self.lo + self.hi) + index * self.P
