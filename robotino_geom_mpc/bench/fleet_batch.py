"""Would a fleet controller gain by stepping its robots together? B robots' control steps one at a time (the float
form each robot's `ControllerLoop` runs, `MotionController.step`) beside one `MotionControllerBatch.step` over the B
of them (the batch form the study runs), in the same process, passes interleaved.

Each robot tracks paper-circle from its own measured states (`controller_step.step_inputs`, a seed per robot); the
two sides must give the same voltages (1e-9) or the benchmark fails. Figures per fleet size B: the time per robot
and tick of each side (``fleet_batch_<B>_one_at_a_time_us``, ``fleet_batch_<B>_batched_us``) and their ratio
``fleet_batch_<B>_one_at_a_time_over_batched`` (above 1: batching is faster). The controller's protocol around
the step (checks, blend, statuses) is per robot either way and not in these figures.
"""

from __future__ import annotations

import numpy as np

from robotino_geom_mpc.bench.controller_step import step_inputs
from robotino_geom_mpc.bench.registry import BenchmarkError, benchmark, median_per_call
from robotino_geom_mpc.control.motion_batch import MotionControllerBatch
from robotino_geom_mpc.control.motion_controller import MotionController

__all__ = ["FLEET_SIZES", "bench_fleet_batch"]

FLEET_SIZES = (1, 5, 10, 20)


@benchmark("fleet_batch", "B robots' control steps one at a time (each robot's loop) vs one batched step over "
           "the B, per robot and tick")
def bench_fleet_batch(quick: bool) -> dict[str, float]:
    """Median time per robot and tick of each side for B in `FLEET_SIZES`, and their ratio."""
    steps, repeats = (100, 3) if quick else (500, 5)
    figures: dict[str, float] = {}
    for size in FLEET_SIZES:
        inputs = [step_inputs(steps, seed=k) for k in range(size)]
        robot, control = inputs[0][2], inputs[0][3]
        X = np.stack([x for x, _, _, _ in inputs], axis=1)  # (steps, B, 6)
        previews = np.stack([p for _, p, _, _ in inputs], axis=1)  # (steps, B, N, 3)
        controllers = [MotionController(robot, control) for _ in range(size)]

        def one_at_a_time() -> np.ndarray:
            for k, controller in enumerate(controllers):
                controller.reset()
                controller.start_at(*X[0, k, 0::2].tolist())
            return np.array([[c.step(X[t, k], previews[t, k]).voltages for k, c in enumerate(controllers)]
                             for t in range(steps)])

        def batched() -> np.ndarray:
            batch = MotionControllerBatch([robot] * size, control, [control.odometry_twist] * size, X[0, :, 0::2])
            return np.array([batch.step(X[t], previews[t])[0] for t in range(steps)])

        difference = float(np.max(np.abs(one_at_a_time() - batched())))
        if not difference <= 1e-9:
            raise BenchmarkError(f"fleet_batch: B = {size}: the batched voltages differ by {difference:.3g} V")
        each_s, batch_s = median_per_call([one_at_a_time, batched], steps * size, repeats)
        figures[f"fleet_batch_{size}_one_at_a_time_us"] = each_s * 1e6
        figures[f"fleet_batch_{size}_batched_us"] = batch_s * 1e6
        figures[f"fleet_batch_{size}_one_at_a_time_over_batched"] = each_s / batch_s
    return figures
