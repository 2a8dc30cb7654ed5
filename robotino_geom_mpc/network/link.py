"""One direction of an emulated radio link: fixed delay, uniform jitter, Gilbert-Elliott bursty loss, duplication.

The robot (the plant node, or the offline loop) sends every packet of one
direction through one `Link`; the link says when (in the sender's clock, the
robot's) the packet is delivered: never, once, or twice. It is seeded and
draws a fixed number of variates per packet, so two runs with the same seed
and the same sequence of `Link.transmit` calls deliver at the same times
(the lockstep DDS loop reproduces the offline loop this way).

Distribution (per packet n, sent at s_n)
----------------------------------------
* Loss: a two-state Gilbert-Elliott chain (Gilbert's special case: every
  packet is lost in the bad state, none in the good one). From good to bad
  with probability p, from bad back to good with probability q = 1 / B, so
  a loss burst lasts B packets on average (geometric) and the long-run loss
  probability is P = p / (p + q), i.e. p = P q / (1 - P). The chain starts
  in its stationary distribution. B = 1 makes losses isolated (never two
  in a row; independent losses of probability P would have B = 1 / (1 - P)).
  p <= 1 needs P <= B / (B + 1).
* Delay: a delivered packet arrives at s_n + D + J_n, J_n uniform in [0, J],
  independent per packet. A later packet can overtake an earlier one when
  their send times differ by less than J: reordering falls out of jitter.
* Duplication: with probability d a delivered packet arrives a second
  time, at s_n + D + J'_n with its own uniform jitter draw.

Each packet uses four uniforms of the generator (loss, jitter, duplicate,
second jitter), drawn whether used or not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robotino_geom_mpc.errors import RobotinoError

__all__ = ["LinkError", "LinkParams", "Link", "MAX_DELAY_S"]

MAX_DELAY_S = 10.0
"""Largest delay and jitter a link takes [s]: a radio link beyond it is a broken one, not a slow one."""

_BLOCK = 1024  # packets' uniforms drawn per call to the generator


class LinkError(RobotinoError, ValueError):
    """A link parameter out of range, named in the message (e.g. ``link.loss must be in [0, 1)``)."""


@dataclass(frozen=True)
class LinkParams:
    """One direction of the link (the module docstring gives the distribution).

    Attributes
    ----------
    delay_s
        Fixed part D of the one-way delay [s], in [0, `MAX_DELAY_S`].
    jitter_s
        Upper bound J of the uniform jitter added per packet [s], in [0, `MAX_DELAY_S`].
    loss
        Long-run loss probability P, in [0, 1).
    burst_length
        Mean length B of a loss burst [packets], >= 1, with P <= B / (B + 1).
    duplicate
        Probability d that a delivered packet arrives twice, in [0, 1).
    """

    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    burst_length: float = 1.0
    duplicate: float = 0.0

    def __post_init__(self) -> None:
        for name in ("delay_s", "jitter_s", "loss", "burst_length", "duplicate"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise LinkError(f"link.{name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        for name in ("delay_s", "jitter_s"):
            if not 0.0 <= getattr(self, name) <= MAX_DELAY_S:
                raise LinkError(f"link.{name} must be in [0, {MAX_DELAY_S:g}] s, got {getattr(self, name)!r}")
        for name in ("loss", "duplicate"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise LinkError(f"link.{name} must be in [0, 1), got {getattr(self, name)!r}")
        if self.burst_length < 1.0:
            raise LinkError(f"link.burst_length must be >= 1 packet, got {self.burst_length!r}")
        if self.loss > self.burst_length / (self.burst_length + 1.0):
            raise LinkError(f"link.loss {self.loss:g} needs link.burst_length >= {self.loss / (1.0 - self.loss):g} "
                            f"(a loss P with bursts of B packets needs P <= B / (B + 1)), got {self.burst_length:g}")

    @property
    def enabled(self) -> bool:
        """True when the link does anything: a delay, a jitter, a loss or duplicates."""
        return bool(self.delay_s or self.jitter_s or self.loss or self.duplicate)

    @property
    def transitions(self) -> tuple[float, float]:
        """(p, q): the Gilbert-Elliott chain's probabilities good -> bad and bad -> good."""
        q = 1.0 / self.burst_length
        return self.loss * q / (1.0 - self.loss), q

    @property
    def mean_delay_s(self) -> float:
        """Mean one-way delay of a delivered packet, D + J / 2 [s]."""
        return self.delay_s + 0.5 * self.jitter_s

    @classmethod
    def from_ms(cls, delay_ms: float = 0.0, jitter_ms: float = 0.0, loss: float = 0.0, burst_length: float = 1.0,
                duplicate: float = 0.0) -> LinkParams:
        """The parameters from milliseconds (the command line's unit)."""
        return cls(delay_ms * 1e-3, jitter_ms * 1e-3, loss, burst_length, duplicate)


class Link:
    """One direction of the emulated link: when each packet arrives, seeded and deterministic.

    Parameters
    ----------
    params
        The direction's parameters.
    seed
        Seed of the direction's own generator (`numpy.random.default_rng`).

    Attributes
    ----------
    sent, lost, duplicated
        Counts of packets offered, lost and delivered twice.
    """

    def __init__(self, params: LinkParams, seed: int) -> None:
        self.params = params
        self._rng = np.random.default_rng(seed)
        self._p, self._q = params.transitions
        self._uniforms: list[list[float]] = []
        self._next = 0
        # the chain's start: bad with the stationary probability P (the first uniform of the stream)
        self._bad = self._draw()[0] < params.loss
        self.sent = self.lost = self.duplicated = 0

    def _draw(self) -> list[float]:
        if self._next == len(self._uniforms):
            self._uniforms, self._next = self._rng.random((_BLOCK, 4)).tolist(), 0
        row = self._uniforms[self._next]
        self._next += 1
        return row

    def transmit(self, send_time_s: float) -> list[float]:
        """The delivery times of a packet sent at `send_time_s`: [] lost, [t] delivered, [t1, t2] twice (t1 <= t2)."""
        u_loss, u_jitter, u_duplicate, u_jitter2 = self._draw()
        p = self.params
        self.sent += 1
        # the chain moves before the packet: the packet's own state decides its fate
        self._bad = u_loss >= self._q if self._bad else u_loss < self._p
        if self._bad:
            self.lost += 1
            return []
        first = send_time_s + p.delay_s + p.jitter_s * u_jitter
        if u_duplicate >= p.duplicate:
            return [first]
        self.duplicated += 1
        second = send_time_s + p.delay_s + p.jitter_s * u_jitter2
        return sorted((first, second))
