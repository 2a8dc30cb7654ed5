"""The offline closed loop of B runs at once: `simulation.run_scenario` with a batch axis.

Every tick does for all runs together what `run_scenario` does for one
(measure, preview, control step, record, plant step; see its notes), with
the array forms of the equations: `model.plant_batch.PlantBatch`,
`model.encoders.EncoderOdometryBatch`, `control.motion_batch.MotionControllerBatch`.
Each run keeps its own plant, controller model, odometry model, noise seed
and slip, and gives the `RunData` its own `run_scenario` gives (to rounding:
the products sum in another order). The Python cost of a tick is paid once
per batch, not once per run.

Routed per run (`run_scenario`): the constrained mode (its QP's active set is
per run) and the cmd_vel command interface. The batch's runs have no compute
times (their `RunData.compute_time_s` is None).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from robotino_geom_mpc.control.motion_batch import MotionControllerBatch
from robotino_geom_mpc.control.motion_controller import state_from_odometry
from robotino_geom_mpc.model.encoders import CONTROLLER_TWIST, DEFAULT_COUNTS_PER_REV, ODOMETRY_MODELS, \
    EncoderOdometryBatch
from robotino_geom_mpc.model.plant_batch import PlantBatch
from robotino_geom_mpc.offline.results import RunData
from robotino_geom_mpc.offline.simulation import SimulationError, run_scenario, run_ticks
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.scenarios import get_scenario

__all__ = ["RunSetting", "run_batch"]


@dataclass(frozen=True)
class RunSetting:
    """One run of a batch: the keyword arguments of `run_scenario` that differ between runs.

    Attributes
    ----------
    robot
        The robot the scenario's controller model is made from (`run_scenario`'s `robot`).
    plant_robot
        The true robot of the plant; `robot` if None.
    seed, odometry_noise, odometry, encoder_counts_per_rev, wheel_slip_std
        As for `run_scenario` (noise None: the scenario's).
    """

    robot: RobotinoParams
    plant_robot: RobotinoParams | None = None
    seed: int = 0
    odometry_noise: tuple[float, float] | None = None
    odometry: str = "ideal"
    encoder_counts_per_rev: int = DEFAULT_COUNTS_PER_REV
    wheel_slip_std: float = 0.0


def _per_run(scenario: str, control: ControlParams, settings: Sequence[RunSetting], duration_s: float | None,
             command_interface: str) -> list[RunData]:
    return [run_scenario(scenario, s.robot, control, duration_s=duration_s, seed=s.seed, plant_robot=s.plant_robot,
                         odometry_noise=s.odometry_noise, odometry=s.odometry,
                         encoder_counts_per_rev=s.encoder_counts_per_rev, wheel_slip_std=s.wheel_slip_std,
                         command_interface=command_interface) for s in settings]


def run_batch(
    scenario: str, control: ControlParams, settings: Sequence[RunSetting], *, duration_s: float | None = None,
    command_interface: str = "voltages",
) -> list[RunData]:
    """Simulate the runs `settings` of one scenario in closed loop, stepped together.

    Parameters
    ----------
    scenario
        A name of `scenarios.SCENARIOS`.
    control
        The controller settings all runs share.
    settings
        The runs (B >= 1).
    duration_s, command_interface
        As for `run_scenario`.

    Returns
    -------
    list of RunData
        One per setting, in order: what `run_scenario` returns for it (without compute times).

    Raises
    ------
    scenarios.ScenarioError, SimulationError
        As `run_scenario` (a bad setting of any run fails the batch, before any step).
    """
    spec = get_scenario(scenario)
    if not settings:
        raise SimulationError("a batch needs at least one run")
    if control.mode != "closed_form" or command_interface != "voltages":
        return _per_run(scenario, control, settings, duration_s, command_interface)
    B = len(settings)
    noises = []
    for s in settings:
        noise = (spec.noise.position_m, spec.noise.yaw_rad) if s.odometry_noise is None else s.odometry_noise
        noise = tuple(float(v) for v in noise)
        if len(noise) != 2 or not all(math.isfinite(v) and v >= 0.0 for v in noise):
            raise SimulationError(f"odometry_noise must be two non-negative numbers, got {s.odometry_noise!r}")
        if s.odometry not in ODOMETRY_MODELS:
            raise SimulationError(f"odometry model must be one of {', '.join(ODOMETRY_MODELS)}, got {s.odometry!r}")
        noises.append(noise)
    reference = spec.make_reference()
    Ts, N = control.period_s, control.horizon
    n = run_ticks(reference.duration_s if duration_s is None else duration_s, Ts)

    plant = PlantBatch([s.plant_robot if s.plant_robot is not None else s.robot for s in settings])
    encoders = np.array([s.odometry == "encoders" for s in settings])
    slips = np.array([s.wheel_slip_std if s.odometry == "encoders" else 0.0 for s in settings])
    normals = None
    if slips.any():  # the slip's own stream per run, default_rng((seed, 1)), drawn ahead: three per update
        normals = np.zeros((n, B, 3))
        for b in np.flatnonzero(slips):
            normals[:, b] = np.random.default_rng((int(settings[b].seed), 1)).standard_normal((n, 3))
    source = EncoderOdometryBatch(plant, np.array([s.encoder_counts_per_rev for s in settings]), slips, normals) \
        if encoders.any() else None
    twists = [CONTROLLER_TWIST.get(s.odometry, control.odometry_twist) for s in settings]
    start = reference.position(np.zeros(1))[0]
    controller = MotionControllerBatch([spec.controller_model(s.robot) for s in settings], control, twists,
                                       np.tile(start, (B, 1)))
    draws = np.zeros((n, B, 3))  # each run's pose noise, drawn at once as `run_scenario` draws it
    for b, (std_position, std_yaw) in enumerate(noises):
        if std_position or std_yaw:
            draws[:, b] = np.random.default_rng(settings[b].seed).normal(
                0.0, (std_position, std_position, std_yaw), (n, 3))

    targets = reference.position(np.arange(n + N + 1) * Ts)
    poses, measured, voltages, currents = (np.empty((n, B, 3)) for _ in range(4))
    saturated = np.empty((n, B), dtype=bool)
    rows = encoders[:, None]
    for k in range(n):
        true_pose, twist = plant.odometry()
        pose = true_pose
        if source is not None:
            pose_encoders, twist_encoders = source.update()
            pose, twist = np.where(rows, pose_encoders, pose), np.where(rows, twist_encoders, twist)
        pose = pose + draws[k]
        X = state_from_odometry(pose, twist)
        volts, saturated[k] = controller.step(X, targets[k + 1 : k + N + 1])
        poses[k], measured[k], voltages[k] = true_pose, pose, volts
        currents[k] = plant.step(volts, Ts)

    t = np.arange(n) * Ts
    return [
        RunData(
            scenario=scenario, t=t, pose=poses[:, b], reference=targets[:n], odometry=measured[:, b],
            currents=currents[:, b], voltages=voltages[:, b], control_period_s=Ts, horizon=N,
            nominal_current_a=s.robot.nominal_current_a, supply_voltage_v=s.robot.supply_voltage_v,
            flags={"saturated": saturated[:, b].copy(), "infeasible": np.zeros(n, dtype=bool)},
            meta={
                "seed": int(s.seed), "mode": control.mode, "odometry_noise": list(noises[b]), "odometry": s.odometry,
                "command_interface": command_interface,
                **({"encoder_counts_per_rev": int(s.encoder_counts_per_rev), "wheel_slip_std": float(s.wheel_slip_std)}
                   if s.odometry == "encoders" else {}),
                "controller_mismatch": None if spec.mismatch is None else asdict(spec.mismatch),
                "plant_params": "plant_robot" if s.plant_robot is not None else "robot",
            },
        )
        for b, s in enumerate(settings)
    ]
