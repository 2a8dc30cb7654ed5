"""The controller node through the real Robotino's chain (``chain.active`` on; realtime, cmd_vel).

With ``chain.active: enabled`` the controller node steps `control.chain_controller.ChainController` (built from
its ``chain.*``: the preset, or `identify`'s file) on each odometry instead of the paper's MPC, and
publishes its twist on ``cmd_vel`` (`control.chain_tracking.ChainTracker` steps it, shared with the replay of
a chain recording). The odometry stamps are the driver's dispatch times: two messages of
one driver pass share a stamp and both are used (the newer sample comes second), and a stamp older than
``odom_timeout_s`` is used too (it is a dispatch time; the controller predicts over the delay). Each zero
twist the node sends (a refused input, its watchdog) is noted in the controller's command model, since the
firmware gets it as any other command. The reference at the
future tick times the controller asks for comes from the newest ``reference_preview``: its point nearest
each time, carried by its velocity and acceleration (second order; the preview spans N Ts, the chain's
command path reaches about 0.15 s ahead). Times are the stamps' seconds since the first odometry.

Disabled (``~/enable`` false, or ``start_enabled`` false), the node answers each odometry with a zero twist, noted
in the command model as well. Enabled again, the controller goes on from its model of the commands sent (no
reference blend as on the MPC path: the blend's acceleration on top of the reference's exceeds the firmware's
ramps, and the one-move plan with its braking limit, (3) of `control.chain_controller`, already brings the robot
back within the ramps: started 0.31 m behind paper-circle, on it again within about 5 s, test_start_disabled).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robotino_geom_mpc.control.chain_controller import ChainControllerError
from robotino_geom_mpc.control.chain_tracking import ChainTracker
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


class ChainControl(ChainTracker):
    """The node's `control.chain_tracking.ChainTracker` (module docstring)."""

    def control(self, node: Any, stamp: int, X: np.ndarray) -> None:
        """The node's step (enabled): the twist on cmd_vel; a refused input as the node refuses one."""
        try:
            twist = self.step(stamp, node._now_ns(), X, node.latest_preview)
        except ChainControllerError as exc:
            node._reject(stamp, "input", "controller", str(exc))
            return
        node.last_odom_ns = stamp
        node.outputs.answer(stamp, twist)
