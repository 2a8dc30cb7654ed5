"""The controller node through the real Robotino's chain (``chain.active`` on; realtime, cmd_vel).

With ``chain.active: enabled`` the controller node steps `control.chain_controller.ChainController` (built from
its ``chain.*``: the preset, or `identify`'s file) on each odometry instead of the paper's MPC, and
publishes its twist on ``cmd_vel``. The odometry stamps are the driver's dispatch times: two messages of
one driver pass share a stamp and both are used (the newer sample comes second), and a stamp older than
``odom_timeout_s`` is used too (it is a dispatch time; the controller predicts over the delay). Each zero
twist the node sends (a refused input, its watchdog) is noted in the controller's command model, since the
firmware gets it as any other command. The reference at the
future tick times the controller asks for comes from the newest ``reference_preview``: its point nearest
each time, carried by its velocity and acceleration (second order; the preview spans N Ts, the chain's
command path reaches about 0.15 s ahead). Times are the stamps' seconds since the first odometry.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from robotino_geom_mpc.control.chain_controller import ChainController, ChainControllerError
from robotino_geom_mpc.model.driver_chain import CHAIN_NODE_DEFAULTS, CHAIN_NODE_SPECS, ChainError, chain_params
from robotino_geom_mpc.params.specs import CHAIN_ACTIVE_SPEC, CHAIN_SPECS
from robotino_geom_mpc.ros.parameters import NodeStartError

__all__ = ["CHAIN_NODE_DEFAULTS", "CHAIN_NODE_SPECS", "ChainControl", "chain_control"]  # the specs for the node


def chain_control(node: Any) -> ChainControl | None:
    """A `ChainControl` for `node` (the controller node) when ``chain.active`` is on, else None."""
    if node.params[CHAIN_ACTIVE_SPEC.name] != "enabled":
        return None
    if node.lockstep or node.params["command_interface"] != "cmd_vel":
        raise NodeStartError("chain.active enabled needs mode realtime and command_interface cmd_vel")
    try:
        chain = chain_params({spec.name: node.params[spec.name] for spec in CHAIN_SPECS},
                             where="the controller's parameters")
    except ChainError as exc:
        raise NodeStartError(str(exc)) from None
    control = ChainControl(chain, node.control.period_s)
    send_zero = node.outputs.send_zero

    def zero_noted() -> None:  # the node's zero twists (refusals, watchdog) reach the firmware too
        control.note_zero(node.get_clock().now().nanoseconds)
        send_zero()
    node.outputs.send_zero = zero_noted
    return control


class ChainControl:
    """One `ChainController` fed from the node's odometry and previews (module docstring)."""

    def __init__(self, chain: Any, preview_period_s: float) -> None:
        self.controller = ChainController(chain)
        self.preview_period_s = preview_period_s
        self.epoch_ns: int | None = None

    def _seconds(self, stamp_ns: int) -> float:
        if self.epoch_ns is None:
            self.epoch_ns = stamp_ns
        return (stamp_ns - self.epoch_ns) * 1e-9

    def reference(self, preview: tuple[int, np.ndarray, np.ndarray, np.ndarray]):  # noqa: ANN201
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
        """A zero twist the node sent at `now_ns` (`ChainController.note_command`)."""
        if self.epoch_ns is not None:
            self.controller.note_command(self._seconds(now_ns), (0.0, 0.0, 0.0))

    def step(self, stamp_ns: int, now_ns: int, X: np.ndarray, preview: tuple) -> list[float]:
        """The twist (v_x, v_y, theta') in base_link for the odometry X (eq. 2's state) stamped `stamp_ns`.

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

    def control(self, node: Any, stamp: int, X: np.ndarray) -> None:
        """The node's step: the twist (zero while disabled) on cmd_vel; a refused input as the node refuses one."""
        try:
            twist = self.step(stamp, node._now_ns(), X, node.latest_preview) if node.enabled else [0.0] * 3
        except ChainControllerError as exc:
            node._reject(stamp, "input", "controller", str(exc))
            return
        node.last_odom_ns = stamp
        node.outputs.answer(stamp, twist)
