"""Time series of one closed-loop run (`RunData`), its metrics and metrics.json.

A run is what the paper's Figs. 4-6 show: the true pose against the
reference, the wheel currents and voltages. `compute_metrics` condenses it
into the numbers runs are compared by (tracking error after a settle time,
peak current including the start transient, peak voltage); `write_metrics`
and `read_metrics` store them as JSON; `save_run` and `load_run` store the
whole run as .npz.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from robotino_geom_mpc.errors import RobotinoError

__all__ = [
    "RunDataError",
    "MetricsError",
    "RunData",
    "wrap_angle",
    "compute_metrics",
    "write_metrics",
    "read_metrics",
    "save_run",
    "load_run",
    "METRIC_KEYS",
]


class RunDataError(RobotinoError, ValueError):
    """A run whose arrays have inconsistent shapes, non-finite values, or bad scalars."""


class MetricsError(RobotinoError, ValueError):
    """A metrics file that cannot be read or is not a JSON object of metrics."""


# keys every metrics.json has, in the order compute_metrics produces them
METRIC_KEYS: tuple[str, ...] = (
    "scenario",
    "samples",
    "duration_s",
    "settle_time_s",
    "samples_after_settle",
    "rms_position_error_m",
    "max_position_error_m",
    "rms_x_error_m",
    "rms_y_error_m",
    "rms_theta_error_rad",
    "final_position_error_m",
    "max_abs_theta_error_rad",
    "peak_current_a",
    "peak_current_after_settle_a",
    "samples_above_nominal_current",
    "current_within_nominal",
    "peak_voltage_v",
    "voltage_within_supply",
    "nominal_current_a",
    "supply_voltage_v",
    "control_period_s",
    "horizon",
)


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def _series(value: object, name: str, columns: int | None, n: int | None) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    want = (n,) if columns is None else (n, columns)
    if (arr.ndim != len(want) or (columns is not None and arr.shape[1] != columns)
            or (n is not None and arr.shape[0] != n)):
        rows = "n" if n is None else str(n)
        shape = f"({rows},)" if columns is None else f"({rows}, {columns})"
        raise RunDataError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise RunDataError(f"{name} contains non-finite values")
    return arr


def _positive(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise RunDataError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(float(value)) or float(value) <= 0.0:
        raise RunDataError(f"{name} must be finite and > 0, got {value!r}")
    return float(value)


@dataclass
class RunData:
    """The time series of one closed-loop run, sampled once per control period.

    Attributes
    ----------
    scenario
        Scenario name (e.g. ``paper-circle``).
    t
        Sample times [s], shape (n,), strictly increasing.
    pose
        True pose (x [m], y [m], theta [rad]), shape (n, 3).
    reference
        Reference pose at the same times, shape (n, 3).
    currents
        Wheel armature currents [A], shape (n, 3).
    voltages
        Wheel voltages applied over the following period [V], shape (n, 3).
    control_period_s, horizon, nominal_current_a, supply_voltage_v
        Control period Ts, MPC horizon N (eqs. 50-53), and the limits the
        currents and voltages are judged against.
    flags
        Optional per-sample boolean series, e.g. ``saturated``, ``infeasible``.
    compute_time_s
        Optional per-sample wall-clock time of the control step [s], shape (n,).
    odometry
        Optional pose the controller measured (the odometry, its noise
        included) at the same times, shape (n, 3); the controller tracks in
        this odom frame, which drifts from the truth with encoder odometry.
    meta
        Optional JSON-serialisable facts about the run (seed, params file, mode).

    Raises
    ------
    RunDataError
        On construction, if shapes disagree, values are not finite, `t` is
        not strictly increasing, or a scalar is not positive.
    """

    scenario: str
    t: np.ndarray
    pose: np.ndarray
    reference: np.ndarray
    currents: np.ndarray
    voltages: np.ndarray
    control_period_s: float
    horizon: int
    nominal_current_a: float
    supply_voltage_v: float
    flags: dict[str, np.ndarray] = field(default_factory=dict)
    compute_time_s: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    odometry: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.scenario, str) or not self.scenario:
            raise RunDataError(f"scenario must be a non-empty string, got {self.scenario!r}")
        self.t = _series(self.t, "t", None, None)
        n = self.t.shape[0]
        if n < 1:
            raise RunDataError("t must hold at least one sample")
        if np.any(np.diff(self.t) <= 0.0):
            raise RunDataError("t must be strictly increasing")
        for name in ("pose", "reference", "currents", "voltages"):
            setattr(self, name, _series(getattr(self, name), name, 3, n))
        self.control_period_s = _positive(self.control_period_s, "control_period_s")
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, (int, np.integer)) or self.horizon < 1:
            raise RunDataError(f"horizon must be a positive integer, got {self.horizon!r}")
        self.horizon = int(self.horizon)
        self.nominal_current_a = _positive(self.nominal_current_a, "nominal_current_a")
        self.supply_voltage_v = _positive(self.supply_voltage_v, "supply_voltage_v")
        flags = {}
        for key, series in dict(self.flags).items():
            arr = np.asarray(series)
            if arr.shape != (n,):
                raise RunDataError(f"flags[{key!r}] must have shape ({n},), got {arr.shape}")
            flags[str(key)] = arr.astype(bool)
        self.flags = flags
        if self.compute_time_s is not None:
            self.compute_time_s = _series(self.compute_time_s, "compute_time_s", None, n)
        if self.odometry is not None:
            self.odometry = _series(self.odometry, "odometry", 3, n)
        if not isinstance(self.meta, dict):
            raise RunDataError(f"meta must be a dict, got {type(self.meta).__name__}")

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    def errors(self, pose: np.ndarray | None = None) -> np.ndarray:
        """Tracking errors pose - reference, shape (n, 3), theta wrapped to [-pi, pi); ``pose``: the true if None."""
        err = (self.pose if pose is None else pose) - self.reference
        err[:, 2] = wrap_angle(err[:, 2])
        return err


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def compute_metrics(run: RunData, settle_time_s: float = 1.0) -> dict[str, Any]:
    """The numbers a run is judged by (the keys of metrics.json, `METRIC_KEYS` first).

    Parameters
    ----------
    run
        The run.
    settle_time_s
        Position errors count from ``t[0] + settle_time_s`` on (the start
        transient from rest is excluded); theta error, peak current and peak
        voltage count over the whole run, start included.

    Returns
    -------
    dict
        Plain Python scalars. Position-error metrics are None when no sample
        lies after the settle time. Further keys: ``<flag>_steps`` (samples
        with the flag set) and, with compute times, ``compute_time_median_s``,
        ``compute_time_p99_s``, ``compute_time_max_s``; with the odometry
        (`RunData.odometry`), the tracking as the controller saw it, in the
        odom frame: ``rms_position_error_odom_m``, ``max_position_error_odom_m``
        and ``rms_theta_error_odom_rad`` (after the settle time), and its
        drift from the truth: ``odometry_drift_final_m`` (x-y distance at the
        last sample) and ``odometry_drift_max_m``. The other keys are against
        the ground truth (the true pose).

    Notes
    -----
    The position error is the Euclidean x-y distance to the reference; the
    theta error is the wrapped angle difference. The paper (Figs. 4-6) reports
    currents within the nominal 0.9 A except at the start, hence both
    ``peak_current_a`` (whole run) and ``peak_current_after_settle_a``.
    """
    settle = float(settle_time_s)
    if not math.isfinite(settle) or settle < 0.0:
        raise RunDataError(f"settle_time_s must be finite and >= 0, got {settle_time_s!r}")
    err = run.errors()
    after = (run.t - run.t[0]) >= settle - 1e-12
    pos_err = np.hypot(err[:, 0], err[:, 1])
    abs_i = np.abs(run.currents)
    peak_current = float(abs_i.max())
    peak_voltage = float(np.abs(run.voltages).max())
    has_after = bool(after.any())

    def after_or_none(fn: Callable[[np.ndarray], float], values: np.ndarray) -> float | None:
        return fn(values[after]) if has_after else None

    metrics: dict[str, Any] = {
        "scenario": run.scenario,
        "samples": run.n,
        "duration_s": float(run.t[-1] - run.t[0]),
        "settle_time_s": settle,
        "samples_after_settle": int(after.sum()),
        "rms_position_error_m": after_or_none(_rms, pos_err),
        "max_position_error_m": after_or_none(lambda v: float(v.max()), pos_err),
        "rms_x_error_m": after_or_none(_rms, err[:, 0]),
        "rms_y_error_m": after_or_none(_rms, err[:, 1]),
        "rms_theta_error_rad": after_or_none(_rms, err[:, 2]),
        "final_position_error_m": float(pos_err[-1]),
        "max_abs_theta_error_rad": float(np.abs(err[:, 2]).max()),
        "peak_current_a": peak_current,
        "peak_current_after_settle_a": after_or_none(lambda v: float(v.max()), abs_i),
        "samples_above_nominal_current": int(np.any(abs_i > run.nominal_current_a, axis=1).sum()),
        "current_within_nominal": peak_current <= run.nominal_current_a,
        "peak_voltage_v": peak_voltage,
        "voltage_within_supply": peak_voltage <= run.supply_voltage_v * (1.0 + 1e-9),
        "nominal_current_a": run.nominal_current_a,
        "supply_voltage_v": run.supply_voltage_v,
        "control_period_s": run.control_period_s,
        "horizon": run.horizon,
    }
    for name, series in sorted(run.flags.items()):
        metrics[f"{name}_steps"] = int(series.sum())
    if run.compute_time_s is not None:
        ct = run.compute_time_s
        metrics["compute_time_median_s"] = float(np.median(ct))
        metrics["compute_time_p99_s"] = float(np.percentile(ct, 99))
        metrics["compute_time_max_s"] = float(ct.max())
    if run.odometry is not None:
        err_odom = run.errors(run.odometry)
        pos_odom = np.hypot(err_odom[:, 0], err_odom[:, 1])
        metrics["rms_position_error_odom_m"] = after_or_none(_rms, pos_odom)
        metrics["max_position_error_odom_m"] = after_or_none(lambda v: float(v.max()), pos_odom)
        metrics["rms_theta_error_odom_rad"] = after_or_none(_rms, err_odom[:, 2])
        drift = np.hypot(*(run.odometry[:, :2] - run.pose[:, :2]).T)
        metrics["odometry_drift_final_m"] = float(drift[-1])
        metrics["odometry_drift_max_m"] = float(drift.max())
    return metrics


def _plain(value: Any) -> Any:
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def write_metrics(metrics: dict[str, Any], path: str | os.PathLike) -> Path:
    """Write metrics as JSON with sorted keys (stable diffs); returns the path.

    Raises
    ------
    MetricsError
        If a value is not finite or not JSON-serialisable.
    """
    path = Path(path)
    try:
        text = json.dumps({str(k): _plain(v) for k, v in metrics.items()}, indent=2, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise MetricsError(f"metrics cannot be written as JSON: {exc}") from None
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n")
    return path


def read_metrics(path: str | os.PathLike) -> dict[str, Any]:
    """Read a metrics.json written by `write_metrics`.

    Raises
    ------
    MetricsError
        If the file cannot be read, is not JSON, or is not a JSON object.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise MetricsError(f"cannot read metrics file {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise MetricsError(f"{path}: not valid JSON (line {exc.lineno})") from None
    if not isinstance(doc, dict):
        raise MetricsError(f"{path}: expected a JSON object of metrics")
    return doc


_ARRAYS = ("t", "pose", "reference", "currents", "voltages")
_SCALARS = ("control_period_s", "horizon", "nominal_current_a", "supply_voltage_v")


def save_run(run: RunData, path: str | os.PathLike) -> Path:
    """Store a run as a compressed .npz (flags as ``flag_<name>``, meta as JSON)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {name: getattr(run, name) for name in _ARRAYS}
    arrays.update({name: np.asarray(getattr(run, name)) for name in _SCALARS})
    arrays["scenario"] = np.asarray(run.scenario)
    arrays["meta"] = np.asarray(json.dumps(run.meta, sort_keys=True))
    arrays.update({f"flag_{name}": series for name, series in run.flags.items()})
    for name in ("compute_time_s", "odometry"):
        if getattr(run, name) is not None:
            arrays[name] = getattr(run, name)
    with path.open("wb") as fh:
        np.savez_compressed(fh, allow_pickle=False, **arrays)
    return path


def load_run(path: str | os.PathLike) -> RunData:
    """Read a run stored by `save_run`.

    Raises
    ------
    RunDataError
        If the file cannot be read, lacks an array, or holds an invalid run.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in (*_ARRAYS, *_SCALARS, "scenario", "meta") if k not in data.files]
            if missing:
                raise RunDataError(f"{path}: missing {', '.join(missing)}")
            return RunData(
                scenario=str(data["scenario"]),
                **{name: data[name] for name in _ARRAYS},
                control_period_s=float(data["control_period_s"]),
                horizon=int(data["horizon"]),
                nominal_current_a=float(data["nominal_current_a"]),
                supply_voltage_v=float(data["supply_voltage_v"]),
                flags={k[len("flag_"):]: data[k] for k in data.files if k.startswith("flag_")},
                compute_time_s=data["compute_time_s"] if "compute_time_s" in data.files else None,
                odometry=data["odometry"] if "odometry" in data.files else None,
                meta=json.loads(str(data["meta"])),
            )
    except (OSError, ValueError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        if isinstance(exc, RunDataError):
            raise
        raise RunDataError(f"cannot read run file {path}: {exc}") from None
