"""A reference moved rigidly onto a pose: the scenario run from where the robot stands.

Every scenario's reference starts at the origin of ``odom`` heading along +x, at rest. Anchored at the
pose p0 = (x0, y0) with heading theta0 it becomes, for all t,

    (x', y')(t) = R(theta0) (x, y)(t) + p0,    theta'(t) = theta(t) + theta0,

with R(a) = [[cos a, -sin a], [sin a, cos a]] the counter-clockwise rotation of REP-103 (x forward, y left,
yaw about +z; docs/theory.md, R(theta) of eqs. 5-9). The velocities, accelerations and jerks of (x, y) are
rotated by R(theta0) and those of theta are unchanged, so the anchored reference is C^3 where the scenario's
is, and at t = 0 it is the pose (x0, y0, theta0) at rest. The scenario's frame is thus the robot's body
frame at the anchor: paper-circle's centre, (0, 0.5) m, lies 0.5 m to the robot's left; point-to-point
waypoints are relative to the robot's start pose.

``goals`` (`reference.goals.GoalReference`) holds its start pose until a goal arrives; goals and paths are
absolute poses in ``odom`` (RViz's and Nav2's), so they are not moved. Anchored, it holds the pose instead of
the origin (the rigid move of the held origin); a goals reference that already has motions is refused (its
motions start from the old start).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.reference.goals import GoalReference
from robotino_geom_mpc.reference.time_law import TrajectoryError, _Backend
from robotino_geom_mpc.reference.trajectories import Reference

__all__ = ["AnchoredReference", "anchored"]


class AnchoredReference(Reference):
    """`reference` moved rigidly onto `pose` (x0 [m], y0 [m], theta0 [rad]) (see the module docstring).

    Attributes
    ----------
    reference
        The scenario's reference (starting at the origin).
    pose
        (3,) the anchor (x0, y0, theta0): the anchored reference's pose at t = 0.
    """

    def __init__(self, reference: Reference, pose: Sequence[float] | np.ndarray) -> None:
        if not isinstance(reference, Reference):
            raise TrajectoryError(f"reference must be a Reference, got {type(reference).__name__}")
        self.reference = reference
        self.pose = checked_array(pose, (3,), "anchor pose (x, y, theta)", TrajectoryError)
        self.name, self.duration_s = reference.name, reference.duration_s
        x0, y0, theta0 = self.pose.tolist()
        self._x0, self._y0, self._theta0 = x0, y0, theta0
        self._c, self._s = math.cos(theta0), math.sin(theta0)

    def _kernel(self, t, xp: _Backend, derivatives: bool) -> list:  # noqa: ANN001
        c, s = self._c, self._s
        values = self.reference._kernel(t, xp, derivatives)
        (x, y, theta), rest = values[0], values[1:]
        out = [(c * x - s * y + self._x0, s * x + c * y + self._y0, theta + self._theta0)]
        out += [(c * dx - s * dy, s * dx + c * dy, dtheta) for dx, dy, dtheta in rest]
        return out


def anchored(reference: Reference, pose: Sequence[float] | np.ndarray) -> Reference:
    """`reference` anchored at `pose`: an `AnchoredReference`, or for ``goals`` a `GoalReference` holding `pose`.

    Raises
    ------
    robotino_geom_mpc.reference.trajectories.TrajectoryError
        A pose that is not three finite numbers, or a goals reference that already has motions.
    """
    if isinstance(reference, GoalReference):
        if reference.pieces:
            raise TrajectoryError("a goals reference is anchored before its first goal (its motions start from "
                                  "the old start pose)")
        start = checked_array(pose, (3,), "anchor pose (x, y, theta)", TrajectoryError)
        return GoalReference(start=tuple(start.tolist()), hold_s=reference.hold_s)
    return AnchoredReference(reference, pose)
