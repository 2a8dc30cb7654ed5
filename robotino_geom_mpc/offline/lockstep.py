"""The controller's inputs of an offline run, as the nodes would send them in lockstep (no rclpy).

The offline loops (`simulation`, `networked`) drive a `loop.controller_loop.ControllerLoop` in lockstep with
the inputs the trajectory node and the plant send each tick (`chain_loop` the same previews in realtime): the
preview of tick k (`PreviewRows`: the reference's pose, velocity and acceleration at t_k + j Ts, j = 0 .. N,
sampled for the whole run at once) and the odometry (the pose and the body twist). In process they travel as
`loop.events.PlanarPreview` and `PlanarOdometry` (`PreviewRows.planar`): the yaw as it is, not a quaternion for the
loop to take apart again (a conversion, not protocol: ``bench --only offline_loop``); `PreviewRows.at` and
`odometry_event` give the messages as ``reference_preview`` and ``odom`` carry them (the yaw as a quaternion), for
driving the loop as the nodes do. `LockstepController` feeds a loop both, in the lockstep plant's order, and
returns the tick's command.
"""

from __future__ import annotations

import math

import numpy as np

from robotino_geom_mpc.control.motion_controller import ControlOutput
from robotino_geom_mpc.loop.controller_loop import ControllerLoop
from robotino_geom_mpc.loop.events import Command, Now, Odometry, PlanarOdometry, PlanarPreview, Preview
from robotino_geom_mpc.loop.inputs import PLANAR_POINT_SIZE, POINT_SIZE
from robotino_geom_mpc.reference.trajectories import Reference

__all__ = ["LockstepController", "ODOM_FRAME", "PreviewRows", "odometry_event"]

ODOM_FRAME = "odom"
"""The frame of the offline previews (the controller's, without a frame prefix)."""


class PreviewRows:
    """The previews of a run: rows j = 0 .. `rows` - 1 of the reference at j Ts, flat, `points` + 1 per preview.

    Parameters
    ----------
    reference
        The scenario's reference.
    period_s
        Ts [s].
    period_ns
        Ts [ns] (the stamps).
    points
        Points after the stamp a preview holds (`ControllerLoop.preview_points`).
    ticks
        The run's ticks.
    """

    def __init__(self, reference: Reference, period_s: float, period_ns: int, points: int, ticks: int) -> None:
        t = np.arange(ticks + points + 1) * period_s
        positions, velocities, accelerations, _ = reference.sample(t)
        half = 0.5 * positions[:, 2]
        zeros = np.zeros(len(t))
        rows = np.column_stack([positions[:, :2], zeros, zeros, np.sin(half), np.cos(half), velocities, accelerations])
        self._flat: list[float] = rows.ravel().tolist()
        self._planar: list[float] = np.column_stack([positions, velocities, accelerations]).ravel().tolist()
        self.positions = positions
        self.period_ns, self._points = period_ns, points + 1

    def at(self, k: int) -> Preview:
        """The preview message of tick k (stamp k Ts), the yaw as a quaternion."""
        start = k * POINT_SIZE
        return Preview(k * self.period_ns, ODOM_FRAME, tuple(self._flat[start:start + self._points * POINT_SIZE]))

    def planar(self, k: int) -> PlanarPreview:
        """The preview of tick k (stamp k Ts) in process: the yaw as it is."""
        start = k * PLANAR_POINT_SIZE
        return PlanarPreview(k * self.period_ns, ODOM_FRAME,
                             tuple(self._planar[start:start + self._points * PLANAR_POINT_SIZE]))


def odometry_event(stamp_ns: int, pose: tuple[float, float, float], twist: tuple[float, float, float]) -> Odometry:
    """The odometry of `pose` (x, y, theta in odom) and `twist` (body) stamped `stamp_ns`."""
    x, y, theta = pose
    return Odometry(stamp_ns, (x, y, 0.0, 0.0, math.sin(0.5 * theta), math.cos(0.5 * theta), *twist))


class LockstepController:
    """A `ControllerLoop` in lockstep on one simulated clock: tick k's preview, then its odometry; the answer.

    Parameters
    ----------
    loop
        The controller's loop (lockstep).
    previews
        The run's previews.

    Attributes
    ----------
    step
        The `MotionController.step` output of the last tick answered (its flags and compute time); None when the
        loop refused that tick.
    """

    def __init__(self, loop: ControllerLoop, previews: PreviewRows) -> None:
        self.loop, self.previews = loop, previews
        self.step: ControlOutput | None = None

    def command(self, k: int, pose: tuple[float, float, float], twist: tuple[float, float, float]
                ) -> tuple[float, float, float]:
        """The command the loop answers to the odometry (pose, twist) of tick k (zero when it refuses it)."""
        t_ns = k * self.previews.period_ns
        now = Now(t_ns, t_ns)
        loop = self.loop
        loop.on_preview(self.previews.planar(k), now)
        for out in loop.on_odometry(PlanarOdometry(t_ns, pose, twist), now):
            if isinstance(out, Command):
                self.step = loop.last_step
                return out.values
        self.step = None
        return (0.0, 0.0, 0.0)
