"""One direction of a network link: fixed delay, uniform jitter, Gilbert-Elliott loss, duplicates (no rclpy).

The contract of /work/wt/NET-API.md (issue 25): `Link.transmit` maps a send time to the list of delivery
times of that packet: [] when lost, [t] delivered once, [t1, t2] delivered twice. A delivery takes
``delay_s`` plus a uniform draw in [0, ``jitter_s``] (packets sent close together can swap: reordering falls
out of it). Losses follow a two-state Gilbert-Elliott chain: in the bad state every packet is lost, in the
good state none; from good to bad with probability p = loss / (B (1 - loss)), from bad to good with 1 / B,
so the long-run loss is ``loss`` and a burst lasts B = ``burst_length`` packets on average (B = 1:
independent losses). A delivered packet is delivered a second time, with its own jitter, with probability
``duplicate``. Seeded: the same seed gives the same deliveries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["Link", "LinkError", "LinkParams"]


class LinkError(RobotinoError, ValueError):
    """A link parameter out of range (named, e.g. ``link.loss must be in [0, 1)``) or a bad send time."""


@dataclass(frozen=True)
class LinkParams:
    """One direction of a link (module docstring)."""

    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    burst_length: float = 1.0
    duplicate: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise LinkError(f"link.{f.name} must be a finite number, got {value!r}")
        if self.delay_s < 0.0 or self.jitter_s < 0.0:
            raise LinkError(f"link.delay_s and link.jitter_s must be >= 0, got {self.delay_s!r}, {self.jitter_s!r}")
        if not 0.0 <= self.loss < 1.0:
            raise LinkError(f"link.loss must be in [0, 1), got {self.loss!r}")
        if self.burst_length < 1.0:
            raise LinkError(f"link.burst_length must be >= 1, got {self.burst_length!r}")
        if not 0.0 <= self.duplicate < 1.0:
            raise LinkError(f"link.duplicate must be in [0, 1), got {self.duplicate!r}")

    @property
    def enabled(self) -> bool:
        """True when any of delay, jitter, loss or duplicate is non-zero."""
        return bool(self.delay_s or self.jitter_s or self.loss or self.duplicate)


class Link:
    """One direction of a link, seeded and deterministic (module docstring)."""

    def __init__(self, params: LinkParams, seed: int) -> None:
        self.params = params
        self._rng = np.random.default_rng(seed)
        self._bad = False
        p = params
        self._to_bad = p.loss / (p.burst_length * (1.0 - p.loss)) if p.loss > 0.0 else 0.0
        self._to_good = 1.0 / p.burst_length

    def _arrival(self, send_time_s: float) -> float:
        jitter = self.params.jitter_s
        return send_time_s + self.params.delay_s + (float(self._rng.uniform(0.0, jitter)) if jitter else 0.0)

    def transmit(self, send_time_s: float) -> list[float]:
        """Delivery times [s] of a packet sent at `send_time_s`: [] lost, [t] or [t1, t2] (duplicated)."""
        if not math.isfinite(send_time_s):
            raise LinkError(f"send_time_s must be finite, got {send_time_s!r}")
        if self._to_bad:
            self._bad = self._rng.random() >= self._to_good if self._bad else self._rng.random() < self._to_bad
            if self._bad:
                return []
        out = [self._arrival(send_time_s)]
        if self.params.duplicate and self._rng.random() < self.params.duplicate:
            out.append(self._arrival(send_time_s))
        return out
