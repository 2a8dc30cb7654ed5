"""One `ChainController` fed with odometry states and reference previews as the controller node gets them.

The plain part of the controller's chain mode (`loop.controller_loop`, which the node and the replay of a chain
recording, `recording.regress_chain`, drive): times are the stamps' seconds since the first odometry stepped; the
reference at the future tick times the controller asks for comes from a preview (its point nearest each time,
carried by its velocity and acceleration: second order; the preview spans N Ts, the chain's command path reaches
about 0.15 s ahead); each zero twist sent outside the controller's answers (a refused input, the watchdog) is noted
in its command model, since the firmware gets it as any other command.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from robotino_geom_mpc.control.chain_controller import ChainController, ChainControllerError

__all__ = ["ChainTracker", "Preview"]

# a reference preview: stamp [ns], positions, velocities, accelerations (each (N + 1, 3): x, y, theta)
Preview = tuple[int, np.ndarray, np.ndarray, np.ndarray]


class ChainTracker:
    """One `ChainController` fed from odometry and previews (module docstring)."""

    def __init__(self, chain: Any, preview_period_s: float) -> None:
        self.controller = ChainController(chain)
        self.preview_period_s = preview_period_s
        self.epoch_ns: int | None = None

    def _seconds(self, stamp_ns: int) -> float:
        if self.epoch_ns is None:
            self.epoch_ns = stamp_ns
        return (stamp_ns - self.epoch_ns) * 1e-9

    def reference(self, preview: Preview) -> Callable[[np.ndarray], np.ndarray]:
        """The reference positions at an array of times [s] (this object's time base) from a preview."""
        stamp_ns, positions, velocities, accelerations = preview
        start = self._seconds(stamp_ns)
        last = len(positions) - 1

        def at(times: np.ndarray) -> np.ndarray:
            offset = np.asarray(times, dtype=float) - start
            j = np.clip(np.round(offset / self.preview_period_s), 0, last).astype(int)
            dt = (offset - j * self.preview_period_s)[:, None]
            return positions[j] + velocities[j] * dt + 0.5 * accelerations[j] * dt**2
        return at

    def note_zero(self, now_ns: int) -> None:
        """A zero twist sent at `now_ns` outside the answers (`ChainController.note_command`)."""
        if self.epoch_ns is not None:
            self.controller.note_command(self._seconds(now_ns), (0.0, 0.0, 0.0))

    def step(self, stamp_ns: int, now_ns: int, X: np.ndarray, preview: Preview) -> list[float]:
        """The twist (v_x, v_y, theta') in base_link for the odometry X (eq. 2's state) stamped `stamp_ns`, taken
        at `now_ns` (when the command will reach the driver).

        Raises
        ------
        ChainControllerError
            A measurement that is not finite, or a stamp before the previous one.
        """
        t = self._seconds(stamp_ns)
        x, vx, y, vy, theta, w = X.tolist()
        c, s = math.cos(theta), math.sin(theta)
        try:
            twist = self.controller.step(t, (x, y, theta), (c * vx + s * vy, -s * vx + c * vy, w),
                                         self.reference(preview), now_s=max(t, self._seconds(now_ns)))
        except ValueError as exc:  # the clock's or the controller's refusal
            raise ChainControllerError(str(exc)) from None
        return list(twist)
