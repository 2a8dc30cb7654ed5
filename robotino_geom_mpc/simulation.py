"""Offline closed loop (Fig. 3): reference -> controller -> simulated Robotino, one control period at a time.

This engine is the reference the ROS 2 nodes reproduce (to 1e-6), so each
tick k (t_k = k Ts, k = 0 .. n-1) does exactly, in this order:

1. measure: ``pose, twist = plant.odometry(rng, noise)`` (pose plus Gaussian
   noise drawn from the run's seeded generator, noise-free body-frame twist),
   ``X = state_from_odometry(pose, twist)`` (both on Python floats here:
   `RobotinoPlant.odometry_floats`, `odometry_state_floats`);
2. ``Y_d`` = the reference positions at t_{k+1} .. t_{k+N} (eq. 54), sampled
   for the whole run at once: rows k+1 .. k+N of ``reference.position(j Ts)``,
   equal to ``preview(reference, t_k, Ts, N)`` to rounding (1e-14);
3. ``out = controller.step(X, Y_d)``;
4. record t_k, the true pose, the reference at t_k, ``out.voltages``;
5. ``plant.step(out.voltages, Ts)`` and record the largest |current| of each
   drive over that period (the plant's substeps), signed like the current
   at the period's end.

The loop keeps numpy out of its per-tick bookkeeping (a call on a 3-vector
costs about as much as a dozen float operations): it collects the ticks'
values and turns them into arrays once, at the end.

The robustness scenario runs paper-circle with a controller whose model is
off: mass +20 %, yaw inertia -20 % (the two errors push the translational and
rotational loops in opposite directions), body friction twice the true one,
and odometry noise 1 mm / 1 mrad.
"""

from __future__ import annotations

import math

import numpy as np
from tqdm import tqdm

from robotino_sim_node.plant import RobotinoPlant

from .core.controller import MotionController, odometry_state_floats
from .core.params import ControlParams, RobotinoParams
from .core.trajectory import make_reference
from .results import RunData

__all__ = [
    "SCENARIOS",
    "SimulationError",
    "ROBUSTNESS_MISMATCH",
    "ROBUSTNESS_NOISE",
    "controller_model",
    "run_scenario",
]

SCENARIOS: tuple[str, ...] = ("paper-circle", "lemniscate", "point-to-point", "robustness")
ROBUSTNESS_MISMATCH = {"mass": 1.2, "inertia": 0.8, "friction": 2.0}  # controller's model / truth
ROBUSTNESS_NOISE = (1e-3, 1e-3)  # odometry noise std: position [m], heading [rad]


class SimulationError(ValueError):
    """An unknown scenario or a bad run setting, named in the message."""


def controller_model(scenario: str, robot: RobotinoParams) -> RobotinoParams:
    """The robot model the controller uses in a scenario (`robot` itself except for robustness)."""
    return robot.scaled(**ROBUSTNESS_MISMATCH) if scenario == "robustness" else robot


def run_scenario(
    scenario: str,
    robot: RobotinoParams,
    control: ControlParams,
    *,
    duration_s: float | None = None,
    seed: int = 0,
    progress: bool = False,
    plant_robot: RobotinoParams | None = None,
    odometry_noise: tuple[float, float] | None = None,
) -> RunData:
    """Simulate one scenario in closed loop.

    Parameters
    ----------
    scenario
        One of `SCENARIOS`.
    robot
        The true robot (the plant) and, except in ``robustness``, the controller's model.
    control
        Controller settings (period, horizon, weights, mode).
    duration_s
        Simulated time; the reference's duration if None.
    seed
        Seed of the odometry noise generator.
    progress
        Show a tqdm progress bar.
    plant_robot
        A different true robot for the plant (mismatch studies); `robot` if None.
    odometry_noise
        (position [m], heading [rad]) noise std; None means the scenario's
        default, (0, 0), or `ROBUSTNESS_NOISE` for ``robustness``.

    Returns
    -------
    RunData
        One sample per control period; flags ``saturated`` and ``infeasible``,
        the controller's compute times, and meta (seed, mode, noise, mismatch).

    Raises
    ------
    SimulationError
        Unknown scenario, non-positive duration or negative noise.
    """
    if scenario not in SCENARIOS:
        raise SimulationError(f"unknown scenario {scenario!r}; valid: {', '.join(SCENARIOS)}")
    if odometry_noise is None:
        odometry_noise = ROBUSTNESS_NOISE if scenario == "robustness" else (0.0, 0.0)
    noise = tuple(float(v) for v in odometry_noise)
    if len(noise) != 2 or not all(math.isfinite(v) and v >= 0.0 for v in noise):
        raise SimulationError(f"odometry_noise must be two non-negative numbers, got {odometry_noise!r}")
    reference = make_reference(scenario)
    duration = reference.duration_s if duration_s is None else float(duration_s)
    if not (math.isfinite(duration) and duration > 0.0):
        raise SimulationError(f"duration_s must be positive, got {duration_s!r}")
    Ts, N = control.period_s, control.horizon
    n = max(1, int(round(duration / Ts)))

    plant = RobotinoPlant(plant_robot if plant_robot is not None else robot)
    controller = MotionController(controller_model(scenario, robot), control)
    rng = np.random.default_rng(seed)

    t = np.arange(n) * Ts
    targets = reference.position(np.arange(n + N + 1) * Ts)  # row j: the reference at j Ts
    # Only floats and arrays are kept per tick (no tuples): nothing for the garbage collector to scan.
    poses, voltages, saturated, infeasible, compute, substep_currents = [], [], [], [], [], []
    for k in tqdm(range(n), desc=scenario, unit="tick", disable=not progress, mininterval=0.5):
        X = odometry_state_floats(*plant.odometry_floats(rng, noise))
        out = controller.step(X, targets[k + 1 : k + N + 1])
        poses.append(plant.pose)
        voltages += out.voltages
        saturated.append(out.saturated)
        infeasible.append(out.infeasible)
        compute.append(out.compute_time_s)
        plant.step(out.voltages, Ts)
        substep_currents.append(plant.substep_currents)
    pose = np.array(poses)
    trace = np.array(substep_currents)  # (n, substeps + 1, 3); the last row is the current at the period's end
    currents = np.copysign(np.abs(trace).max(axis=1), trace[:, -1])

    return RunData(
        scenario=scenario,
        t=t,
        pose=pose,
        reference=targets[:n],
        currents=currents,
        voltages=np.array(voltages).reshape(n, 3),
        control_period_s=Ts,
        horizon=N,
        nominal_current_a=robot.nominal_current_a,
        supply_voltage_v=robot.supply_voltage_v,
        flags={"saturated": np.array(saturated, dtype=bool), "infeasible": np.array(infeasible, dtype=bool)},
        compute_time_s=np.array(compute),
        meta={
            "seed": int(seed),
            "mode": control.mode,
            "odometry_noise": list(noise),
            "controller_mismatch": dict(ROBUSTNESS_MISMATCH) if scenario == "robustness" else None,
            "plant_params": "plant_robot" if plant_robot is not None else "robot",
        },
    )
