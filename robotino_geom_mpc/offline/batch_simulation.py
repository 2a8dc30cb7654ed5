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

`simulate_batch` keeps the series as arrays with the batch axis (`BatchSeries`),
whose `BatchSeries.metrics` is `results.compute_metrics` of every run at once
(the study's path: no per-run objects); `run_batch` cuts them into one
`RunData` per run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from robotino_geom_mpc.control.motion_batch import MotionControllerBatch
from robotino_geom_mpc.control.motion_controller import states_from_odometry
from robotino_geom_mpc.model.encoders import CONTROLLER_TWIST, DEFAULT_COUNTS_PER_REV, ODOMETRY_MODELS, \
    EncoderOdometryBatch
from robotino_geom_mpc.model.plant_batch import PlantBatch
from robotino_geom_mpc.offline.results import RunData, RunDataError, compute_metrics, wrap_angle
from robotino_geom_mpc.offline.simulation import RunConfig, SimulationError, run_scenario, run_ticks
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.scenarios import get_scenario

__all__ = ["RunSetting", "BatchSeries", "simulate_batch", "run_batch", "batch_metrics"]


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
    return [run_scenario(RunConfig(scenario, s.robot, control, duration_s=duration_s, seed=s.seed,
                                   plant_robot=s.plant_robot, odometry_noise=s.odometry_noise, odometry=s.odometry,
                                   encoder_counts_per_rev=s.encoder_counts_per_rev, wheel_slip_std=s.wheel_slip_std,
                                   command_interface=command_interface)) for s in settings]


# its fields in prose, not an Attributes section: the docs would link `pose` and `currents` to four classes'
@dataclass(frozen=True)
class BatchSeries:
    """The series of B runs stepped together, time first: per run what its `RunData` holds.

    Fields: ``scenario`` and ``control``, what every run ran; ``settings``, the runs in order; ``noises``, each
    run's odometry noise (position [m], yaw [rad]); ``t`` and ``reference``, the sample times (n,) and the
    reference poses (n, 3), shared; ``pose``, ``odometry``, ``currents`` and ``voltages``, (n, B, 3) the true
    and measured poses, peak currents and voltages (as in `RunData`); ``saturated``, (n, B) the saturated flags.
    """

    scenario: str
    control: ControlParams
    settings: tuple[RunSetting, ...]
    noises: tuple[tuple[float, float], ...]
    t: np.ndarray
    reference: np.ndarray
    pose: np.ndarray
    odometry: np.ndarray
    currents: np.ndarray
    voltages: np.ndarray
    saturated: np.ndarray

    def run_data(self, b: int) -> RunData:
        """Run b's `RunData` (copies of its series): what `run_scenario` returns for it, without compute times."""
        s, n, control = self.settings[b], len(self.t), self.control
        spec = get_scenario(self.scenario)
        return RunData(
            scenario=self.scenario, t=self.t, pose=self.pose[:, b], reference=self.reference,
            odometry=self.odometry[:, b], currents=self.currents[:, b], voltages=self.voltages[:, b],
            control_period_s=control.period_s, horizon=control.horizon, nominal_current_a=s.robot.nominal_current_a,
            supply_voltage_v=s.robot.supply_voltage_v,
            flags={"saturated": self.saturated[:, b].copy(), "infeasible": np.zeros(n, dtype=bool)},
            meta={
                "seed": int(s.seed), "mode": control.mode, "odometry_noise": list(self.noises[b]),
                "odometry": s.odometry, "command_interface": "voltages",
                **({"encoder_counts_per_rev": int(s.encoder_counts_per_rev), "wheel_slip_std": float(s.wheel_slip_std)}
                   if s.odometry == "encoders" else {}),
                "controller_mismatch": None if spec.mismatch is None else asdict(spec.mismatch),
                "plant_params": "plant_robot" if s.plant_robot is not None else "robot",
            },
        )

    def metrics(self, settle_time_s: float = 1.0) -> list[dict[str, Any]]:
        """`results.compute_metrics` of every run (the same keys and order), computed on the arrays at once.

        Equal to each run's `compute_metrics` to rounding (the means sum in another order).

        Raises
        ------
        RunDataError
            For a negative or non-finite settle time, or non-finite series (as `RunData` would).
        """
        settle = float(settle_time_s)
        if not math.isfinite(settle) or settle < 0.0:
            raise RunDataError(f"settle_time_s must be finite and >= 0, got {settle_time_s!r}")
        for name in ("pose", "odometry", "currents", "voltages"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise RunDataError(f"{name} contains non-finite values")
        t, n, B = self.t, len(self.t), self.pose.shape[1]
        after = (t - t[0]) >= settle - 1e-12
        shared = {"scenario": self.scenario, "samples": n, "duration_s": float(t[-1] - t[0]), "settle_time_s": settle,
                  "samples_after_settle": int(after.sum()), "control_period_s": float(self.control.period_s),
                  "horizon": int(self.control.horizon)}
        rows = []
        for start in range(0, B, _METRIC_CHUNK):  # a few runs at a time: the temporaries stay small
            columns = self._metric_columns(slice(start, start + _METRIC_CHUNK), after)
            order = [key for key in _METRIC_ORDER if key in shared or key in columns]
            rows += [{key: shared[key] if key in shared else columns[key][b] for key in order}
                     for b in range(len(columns["peak_current_a"]))]
        return rows

    def _metric_columns(self, runs: slice, after: np.ndarray) -> dict[str, list[Any]]:
        """The per-run metrics of the runs `runs`, key by key (`metrics`; position errors after `after`).

        Each quantity is one contiguous array (n, runs), its coordinate's own (numpy steps through rows of
        three, the series' layout, four to six times as slowly).
        """
        settings = self.settings[runs]
        nominal = np.array([s.robot.nominal_current_a for s in settings])
        supply = np.array([s.robot.supply_voltage_v for s in settings])
        B, count, n = len(settings), int(after.sum()), len(after)
        pose, measured = _coordinates(self.pose[:, runs]), _coordinates(self.odometry[:, runs])
        reference = self.reference.T[:, :, None]  # (3, n, 1): each coordinate of the reference against the runs

        def errors(pose: np.ndarray) -> np.ndarray:
            err = np.subtract(pose, reference, out=np.empty_like(pose))
            err[2] = wrap_angle(err[2])
            return err

        settled = slice(n - count, None)  # `after` (t increasing): the last `count` samples, a view

        def rms(values: np.ndarray) -> list[float | None]:
            return np.sqrt(np.mean(np.square(values[settled]), axis=0)).tolist() if count else [None] * B

        def peak(values: np.ndarray) -> list[float | None]:
            return values[settled].max(axis=0).tolist() if count else [None] * B

        def largest(series: np.ndarray) -> np.ndarray:  # `largest_abs` of each sample, (n, runs)
            magnitudes = np.abs(_coordinates(series[:, runs]))
            return np.maximum(np.maximum(magnitudes[0], magnitudes[1]), magnitudes[2])

        err = errors(pose)
        position = _length(err[0], err[1])
        current = largest(self.currents)  # each sample's largest |current| (n, runs)
        peak_current = current.max(axis=0)
        peak_voltage = largest(self.voltages).max(axis=0)
        odometry = errors(measured)
        position_odometry = _length(odometry[0], odometry[1])
        drift = _length(measured[0] - pose[0], measured[1] - pose[1])
        return {
            "rms_position_error_m": rms(position), "max_position_error_m": peak(position),
            "rms_x_error_m": rms(err[0]), "rms_y_error_m": rms(err[1]),
            "rms_theta_error_rad": rms(err[2]), "final_position_error_m": position[-1].tolist(),
            "max_abs_theta_error_rad": np.abs(err[2]).max(axis=0).tolist(),
            "peak_current_a": peak_current.tolist(), "peak_current_after_settle_a": peak(current),
            "samples_above_nominal_current": (current > nominal).sum(axis=0).tolist(),
            "current_within_nominal": (peak_current <= nominal).tolist(), "peak_voltage_v": peak_voltage.tolist(),
            "voltage_within_supply": (peak_voltage <= supply * (1.0 + 1e-9)).tolist(),
            "nominal_current_a": nominal.tolist(), "supply_voltage_v": supply.tolist(),
            "infeasible_steps": [0] * B, "saturated_steps": self.saturated[:, runs].sum(axis=0).tolist(),
            "rms_position_error_odom_m": rms(position_odometry), "max_position_error_odom_m": peak(position_odometry),
            "rms_theta_error_odom_rad": rms(odometry[2]), "odometry_drift_final_m": drift[-1].tolist(),
            "odometry_drift_max_m": drift.max(axis=0).tolist(),
        }


def _coordinates(series: np.ndarray) -> np.ndarray:
    """A series (n, B, 3) as its three coordinates, (3, n, B) contiguous (a copy)."""
    out = np.empty((3, *series.shape[:2]))
    out[...] = series.transpose(2, 0, 1)
    return out


def _length(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """sqrt(x^2 + y^2): `compute_metrics`'s hypot to a rounding unit (no overflow at these sizes), ten times as fast."""
    return np.sqrt(x * x + y * y)


_METRIC_CHUNK = 20  # runs whose metrics `BatchSeries.metrics` computes together (a 22 s run's (3, n, 20) in L2)
_METRIC_ORDER = (  # `compute_metrics`'s keys in its order (METRIC_KEYS, the flags sorted, the odometry's)
    "scenario", "samples", "duration_s", "settle_time_s", "samples_after_settle", "rms_position_error_m",
    "max_position_error_m", "rms_x_error_m", "rms_y_error_m", "rms_theta_error_rad", "final_position_error_m",
    "max_abs_theta_error_rad", "peak_current_a", "peak_current_after_settle_a", "samples_above_nominal_current",
    "current_within_nominal", "peak_voltage_v", "voltage_within_supply", "nominal_current_a", "supply_voltage_v",
    "control_period_s", "horizon", "infeasible_steps", "saturated_steps", "rms_position_error_odom_m",
    "max_position_error_odom_m", "rms_theta_error_odom_rad", "odometry_drift_final_m", "odometry_drift_max_m",
)


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
    if control.mode != "closed_form" or command_interface != "voltages":
        get_scenario(scenario)
        if not settings:
            raise SimulationError("a batch needs at least one run")
        return _per_run(scenario, control, settings, duration_s, command_interface)
    series = simulate_batch(scenario, control, settings, duration_s=duration_s)
    return [series.run_data(b) for b in range(len(settings))]


def batch_metrics(
    scenario: str, control: ControlParams, settings: Sequence[RunSetting], *, duration_s: float | None = None,
    settle_time_s: float = 1.0,
) -> list[dict[str, Any]]:
    """`results.compute_metrics` of each run of `run_batch` (the study's rows): on the arrays when stepped together.

    Raises what `run_batch` and `compute_metrics` raise.
    """
    if control.mode != "closed_form":
        return [compute_metrics(data, settle_time_s=settle_time_s)
                for data in run_batch(scenario, control, settings, duration_s=duration_s)]
    return simulate_batch(scenario, control, settings, duration_s=duration_s).metrics(settle_time_s)


def simulate_batch(
    scenario: str, control: ControlParams, settings: Sequence[RunSetting], *, duration_s: float | None = None,
) -> BatchSeries:
    """The closed loop of the runs `settings`, stepped together, as arrays (closed-form mode, voltages).

    Raises
    ------
    scenarios.ScenarioError, SimulationError
        As `run_batch`; SimulationError also for a mode other than the closed form.
    """
    spec = get_scenario(scenario)
    if not settings:
        raise SimulationError("a batch needs at least one run")
    if control.mode != "closed_form":
        raise SimulationError(f"the batched loop is closed-form only, got mode {control.mode!r} (use run_batch)")
    B = len(settings)
    noises = []
    for s in settings:
        given = (spec.noise.position_m, spec.noise.yaw_rad) if s.odometry_noise is None else s.odometry_noise
        noise = tuple(float(v) for v in given)
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
    reading = np.flatnonzero(encoders)  # the runs whose odometry the encoders give
    normals = None
    if slips.any():  # the slip's own stream per run, default_rng((seed, 1)), drawn ahead: three per update
        normals = np.zeros((n, len(reading), 3))
        for column, b in enumerate(reading.tolist()):
            if slips[b]:
                normals[:, column] = np.random.default_rng((int(settings[b].seed), 1)).standard_normal((n, 3))
    source = EncoderOdometryBatch(plant, np.array([settings[b].encoder_counts_per_rev for b in reading.tolist()]),
                                  slips[reading], normals, reading) if len(reading) else None
    twists = [CONTROLLER_TWIST.get(s.odometry, control.odometry_twist) for s in settings]
    start = reference.position(np.zeros(1))[0]
    controller = MotionControllerBatch([spec.controller_model(s.robot) for s in settings], control, twists,
                                       np.tile(start, (B, 1)))
    # each run's pose noise, the draws of `run_scenario`'s normal(0, std, (n, 3)): the same standard normals,
    # drawn run by run into one array, then scaled into the loop's layout at once (a third faster than run by run)
    normals = np.zeros((B, n, 3))
    for b, (std_position, std_yaw) in enumerate(noises):
        if std_position or std_yaw:
            np.random.default_rng(settings[b].seed).standard_normal(out=normals[b])
    draws = np.multiply(normals.transpose(1, 0, 2), [(p, p, y) for p, y in noises], out=np.empty((n, B, 3)))
    del normals

    targets = reference.position(np.arange(n + N + 1) * Ts)
    poses, measured, voltages, currents = (np.empty((n, B, 3)) for _ in range(4))
    saturated = np.empty((n, B), dtype=bool)
    for k in range(n):
        poses[k], twist = plant.odometry()
        pose = np.add(poses[k], draws[k], out=measured[k])
        if source is not None:
            pose_encoders, twist[reading] = source.update()
            pose[reading] = pose_encoders + draws[k, reading]
        volts, saturated[k] = controller.step(states_from_odometry(pose, twist), targets[k + 1 : k + N + 1])
        voltages[k] = volts
        plant.advance(volts, Ts, currents[k])

    return BatchSeries(scenario, control, tuple(settings), tuple(noises), np.arange(n) * Ts, targets[:n], poses,
                       measured, currents, voltages, saturated)
