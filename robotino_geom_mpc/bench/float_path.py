"""Is the per-tick float path needed? One control step and each of its kernels on Python floats beside the array
kernels that serve a batch (the study's), both on one run, in the same process, passes interleaved.

The array kernels (`OdometryFilterBatch.update`, `DecoupledMPCBatch.delta_u`, `DecouplingFieldBatch.forces`,
`MotorKinematicsBatch.speeds_and_rates`, `InverseDriveBatch.step`, and the whole step `MotionControllerBatch.step`)
take a leading batch axis; on one run (B = 1) they pay numpy's per-call overhead on 3-vectors. The one-run
classes' float forms (`OdometryFilter.update`, `DecoupledMPC.delta_u`, `DecouplingField.forces`,
`MotorKinematics.speeds_and_rates`, `InverseDrive.step`, `MotionController.step`) are what the nodes and
`simulate` run each tick. Each figure ``float_path_<kernel>_us`` (float form) sits beside
``array_path_<kernel>_us`` and their ratio ``array_over_float_<kernel>``; the two sides must give the same
numbers (1e-9), or the benchmark fails.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from robotino_geom_mpc.bench.controller_step import step_inputs
from robotino_geom_mpc.bench.registry import BenchmarkError, benchmark, median_per_call
from robotino_geom_mpc.control.estimator import OdometryFilter, OdometryFilterBatch
from robotino_geom_mpc.control.inverse_drive import InverseDrive, InverseDriveBatch
from robotino_geom_mpc.control.motion_batch import MotionControllerBatch
from robotino_geom_mpc.control.motion_controller import MotionController
from robotino_geom_mpc.control.mpc import DecoupledMPCBatch
from robotino_geom_mpc.geometric.decoupling import DecouplingField, DecouplingFieldBatch
from robotino_geom_mpc.model.kinematics import MotorKinematics, MotorKinematicsBatch

__all__ = ["bench_float_path"]


def _agree(name: str, floats: object, arrays: object) -> None:
    difference = float(np.max(np.abs(np.asarray(floats, dtype=float) - np.asarray(arrays, dtype=float))))
    if not difference <= 1e-9:
        raise BenchmarkError(f"float_path: {name}: the float and the array forms differ by {difference:.3g}")


@benchmark("float_path", "the per-tick float forms of one control step and its kernels vs the array kernels at B = 1")
def bench_float_path(quick: bool) -> dict[str, float]:
    """Median time per call of each float form and of its array kernel on one run, and their ratio."""
    steps, repeats = (200, 3) if quick else (2000, 7)
    X, previews, robot, control = step_inputs(steps)
    ones = np.ones((steps, 3))
    u, theta = 0.1 * ones * np.sin(np.arange(steps))[:, None], X[:, 4]
    velocity = X[:, 1::2]
    X_list, u_list, velocity_list = X.tolist(), u.tolist(), velocity.tolist()
    previews_list = [p.tolist() for p in previews]
    controller = MotionController(robot, control)
    mpc, field, kinematics = controller.mpc, DecouplingField(robot), MotorKinematics(robot)
    mpcs, fields, kinematics_batch = DecoupledMPCBatch([robot], control), DecouplingFieldBatch([robot]), \
        MotorKinematicsBatch([robot])
    drive_floats, drive_arrays = InverseDrive(robot, control.period_s), InverseDriveBatch([robot], control.period_s)
    currents, omega = 0.3 * u, 20.0 * velocity

    def batch_step() -> list[np.ndarray]:
        batch = MotionControllerBatch([robot], control, [control.odometry_twist], X[:1, 0::2])
        return [batch.step(X[k : k + 1], previews[k])[0][0] for k in range(steps)]

    tau = control.odometry_filter_time_constant_s or 0.5  # (the preset's; a filter needs one > 0)

    def float_filter() -> list[tuple[float, float, float]]:
        estimator = OdometryFilter(control.period_s, tau, control.odometry_twist)
        estimator.start_at(*X_list[0][0::2])
        return [estimator.update(*X_list[k]) for k in range(steps)]

    def batch_filter() -> list[np.ndarray]:
        estimator = OdometryFilterBatch(control.period_s, tau, [control.odometry_twist], X[:1, 0::2])
        return [estimator.update(X[k : k + 1])[0] for k in range(steps)]

    def float_step() -> list[tuple[float, ...]]:
        controller.reset()
        controller.start_at(*X[0, 0::2].tolist())
        return [controller.step(X[k], previews[k]).voltages for k in range(steps)]

    pairs: dict[str, tuple[Callable[[], object], Callable[[], object]]] = {
        "step": (float_step, batch_step),
        "filter": (float_filter, batch_filter),
        "mpc": (lambda: [mpc.delta_u(X_list[k], u_list[k], previews_list[k]) for k in range(steps)],
                lambda: [mpcs.delta_u(X[k : k + 1], u[k : k + 1], previews[k])[0] for k in range(steps)]),
        "field": (lambda: [field.forces(theta[k], u_list[k]) for k in range(steps)],
                  lambda: [fields.forces(theta[k : k + 1], u[k : k + 1])[0] for k in range(steps)]),
        "kinematics": (
            lambda: [kinematics.speeds_and_rates(theta[k], velocity_list[k], u_list[k])[0] for k in range(steps)],
            lambda: [kinematics_batch.speeds_and_rates(theta[k : k + 1], velocity[k : k + 1], u[k : k + 1])[0][0]
                     for k in range(steps)]),
        "drive": (lambda: [drive_floats.step(currents[k].tolist(), omega[k].tolist(), u_list[k])[0]
                           for k in range(steps)],
                  lambda: [drive_arrays.step(currents[k : k + 1], omega[k : k + 1], u[k : k + 1])[0][0]
                           for k in range(steps)]),
    }
    figures: dict[str, float] = {}
    for name, (floats, arrays) in pairs.items():
        drive_floats.reset()
        drive_arrays.reset()
        first = floats()
        _agree(name, first, arrays())
        float_s, array_s = median_per_call([floats, arrays], steps, repeats)
        figures[f"float_path_{name}_us"] = float_s * 1e6
        figures[f"array_path_{name}_us"] = array_s * 1e6
        figures[f"array_over_float_{name}"] = array_s / float_s
    return figures
