"""A run's `RunData`, metrics.json and figures from a recording alone (the same code path `run` uses).

How a recording maps onto `results.RunData` (one sample per control tick k):

* tick times t_k: the header stamps of ``ground_truth/odom`` (the first
  message of each stamp: a lockstep tick the plant resends counts once),
  relative to the first tick;
* pose: ``ground_truth/odom`` position and yaw (unwrapped);
* odometry (the pose the controller measured, in the odom frame): the
  ``odom`` message stamped t_k (its first), when every tick has one;
* reference: point 0 of the ``reference_preview`` stamped t_k (the
  reference at t_k itself), else the ``reference_path`` pose stamped t_k
  (linear interpolation between path samples otherwise);
* currents: the signed peak currents of the period after tick k, which the
  plant publishes once it has integrated that period (as `simulation`
  records them): the first ``wheel_currents`` published after the tick's
  ``ground_truth/odom`` and before the next tick's (by publish time);
* voltages: the controller's answer to tick k, found through its
  ``diagnostics`` (stamped t_k, published right after the voltages: the
  last ``wheel_voltages`` published before it), else the first
  ``wheel_voltages`` published after the tick's ``odom``; the diagnostics
  also give the ``saturated`` / ``infeasible`` flags and the compute time.
  A cmd_vel run (no ``wheel_voltages``: the controller sent twists on
  ``cmd_vel``) takes the plant's ``applied_voltages`` instead, the mean
  voltages its wheel-speed PI loops applied over the period after tick k (as
  `simulation` records a cmd_vel run), paired with the tick as the currents are;
* scalars (control period, horizon, nominal current, supply voltage) and
  the scenario name: from the run parameters the recorder stores (MCAP
  metadata record ``robotino_geom_mpc``), else from a parameter file given
  by the caller, else from the default preset (noted in ``meta``).

Ticks lacking one of these (e.g. the last tick, answered after the recorder
stopped) are left out; ``meta["ticks_dropped"]`` counts them.

A recording without ``ground_truth/odom`` (a real robot: nothing knows the true pose) is reported as odometry
sees it (`recorded_run`, ``meta["truth"]`` ``"odometry"``; else ``"ground_truth"`` and the mapping above):

* tick times and pose: the distinct ``odom`` stamps and, per stamp, its last message (a driver that dispatches
  two samples under one stamp sends the newer second);
* reference: the reference the controller had, the newest ``reference_preview`` stamped at or before the tick
  (within its span of N Ts), carried to the tick as the controller carries it (`reference.trajectories.preview_at`:
  point 0 by its velocity and acceleration, second order; a longer preview's row of the periods elapsed first),
  else the ``reference_path`` as above;
* currents, voltages and the commanded twist (``cmd_vel``): the newest message of each published before the
  tick's next odometry (the value in force over the tick); ticks before the first currents or voltages are left
  out, a twist before the first ``cmd_vel`` is zero (nothing commanded yet). Where ``wheel_currents`` (or any
  voltages) are missing, as through the real driver, `RecordedRun.commands` holds the commanded body twist and
  the wheel speeds it asks for, drawn instead, and the metrics of the missing series are None.
"""

from __future__ import annotations

import os
from bisect import bisect_left, bisect_right
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from robotino_geom_mpc.params.specs import ControlParams, ParamError, params_from_values
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.definitions import _typestore
from robotino_geom_mpc.model.kinematics import MotorKinematics
from robotino_geom_mpc.offline.results import RunData, compute_metrics, write_metrics
from robotino_geom_mpc.recording.link_report import link_figures
from robotino_geom_mpc.recording.odometry_timing import odometry_timing
from robotino_geom_mpc.recording.topics import (
    by_publish_time,
    controller_diagnostics,
    controller_diagnostics_of_message,
    converted_by_publish_time,
    find_topic,
    read_controller_diagnostics,
    run_parameters,
)
from robotino_geom_mpc.reference.trajectories import preview_at
from robotino_geom_mpc.ros.cdr import float64_array, odometry_pose, preview_start, values_of
from robotino_geom_mpc.ros.decode import (
    float64_array_of_message,
    odometry_pose_of_message,
    preview_start_of_message,
    stamp_ns,
    yaw_of,
)

__all__ = [
    "RecordedRun",
    "recorded_run",
    "find_topic",
    "run_parameters",
    "resolve_parameters",
    "by_publish_time",
    "controller_diagnostics",
    "stamp_ns",
    "yaw",
    "run_data_from_bag",
    "report_bag",
    "Report",
    "write_report",
]



def yaw(q: Any) -> float:
    """Yaw (rad) of a quaternion message (ZYX convention)."""
    return yaw_of(q.x, q.y, q.z, q.w)


def resolve_parameters(bag: BagReader, params_file: str | os.PathLike | None):
    """(robot, control, stored scenario, source): `params_file` if given, else the stored values, else the preset."""
    values, scenario = run_parameters(bag)
    if params_file is not None:
        robot, control = load_params(params_file)
        source = str(params_file)
    elif values is not None:
        try:
            robot, control = params_from_values(values, f"the run parameters stored in {bag.path}")
        except ParamError as exc:
            raise BagError(str(exc)) from None
        source = "recording"
    else:
        robot, control = load_params()
        source = "default preset (the recording stores no run parameters)"
    return robot, control, scenario, source


def _values_by_publish_time(bag: BagReader, topic: str | None, read: Callable[[bytes], Any],
                            of_message: Callable[[Any], Any]) -> list[tuple[int, Any]]:
    """`by_publish_time` of the values `read` takes from each message's bytes (`cdr_values`; rosbags' decoder
    and `of_message` for bytes it does not walk): a tenth of the cost of decoding whole messages.
    """
    store = _typestore()
    return converted_by_publish_time(bag, topic, lambda m: values_of(
        m.data, read, of_message, lambda: store.deserialize_cdr(m.data, m.type)))


def _first_per_stamp(items: list[tuple[int, tuple[int, Any]]]) -> dict[int, tuple[int, Any]]:
    """(publish time, (stamp, value)) items -> stamp -> (publish time, value) of the first published."""
    out: dict[int, tuple[int, Any]] = {}
    for publish, (stamp, value) in items:
        out.setdefault(stamp, (publish, value))
    return out


def _first_after(times: list[int], items: list, t: int, before: int | None = None):
    i = bisect_right(times, t)
    if i < len(items) and (before is None or times[i] < before):
        return items[i][1]
    return None


def _applied_voltages_topic(bag: BagReader) -> str:
    """The ``applied_voltages`` topic of a cmd_vel run; BagError naming both command topics if there is none."""
    topic = find_topic(bag, "applied_voltages", "std_msgs/msg/Float64MultiArray", False)
    if topic is None:
        raise BagError(f"{bag.path}: no 'wheel_voltages' (nor, for a cmd_vel run, 'applied_voltages') topic of "
                       "type std_msgs/msg/Float64MultiArray in the recording")
    return topic


# its fields in prose, not an Attributes section: the docs would link `currents` and `twist` to other classes'
@dataclass(frozen=True)
class RecordedRun:
    """A recorded run (`recorded_run`): its `RunData` and what the recording lacked.

    ``run`` is the run; ``run.meta["truth"]`` is ``"ground_truth"`` or ``"odometry"``. The flags ``currents`` and
    ``voltages`` say whether the recording holds wheel currents and voltages (``wheel_voltages`` or
    ``applied_voltages``); where it has none, the run's series are zeros standing in, never to be read as data.
    Without currents, ``twist`` is the commanded body twist (v_x, v_y [m/s], theta' [rad/s] in base_link, from
    ``cmd_vel``) per tick, shape (n, 3), and ``wheel_speeds`` the wheel speeds that twist asks for [rad/s] per tick,
    shape (n, 3), drawn instead; else both are None.
    """

    run: RunData
    currents: bool = True
    voltages: bool = True
    twist: np.ndarray | None = None
    wheel_speeds: np.ndarray | None = None

    @property
    def truth(self) -> str:
        """``"ground_truth"`` or ``"odometry"``."""
        return self.run.meta["truth"]


def run_data_from_bag(
    bag: BagReader | str | os.PathLike,
    params_file: str | os.PathLike | None = None,
    scenario: str | None = None,
) -> RunData:
    """The `RunData` of a recorded run (`recorded_run`'s; see the module docstring for the mapping)."""
    return recorded_run(bag, params_file, scenario).run


def recorded_run(
    bag: BagReader | str | os.PathLike,
    params_file: str | os.PathLike | None = None,
    scenario: str | None = None,
) -> RecordedRun:
    """Extract a recorded run: against ``ground_truth/odom`` where recorded, else as odometry sees it.

    Raises
    ------
    BagError
        If the bag lacks ``odom`` (without ground truth), the currents or the voltages of a run with ground truth,
        or no tick has all its data.
    """
    if not isinstance(bag, BagReader):
        bag = BagReader(bag)
    robot, control, stored_scenario, source = resolve_parameters(bag, params_file)
    meta = {"source": "recording", "bag": str(bag.path), "parameters": source, "bag_problems": list(bag.problems)}
    name = scenario or stored_scenario or "recording"
    truth_topic = find_topic(bag, "ground_truth/odom", "nav_msgs/msg/Odometry", False)
    if truth_topic is None:
        return _odometry_run(bag, robot, control, name, meta)
    return RecordedRun(_ground_truth_run(bag, truth_topic, robot, control, name, meta))


def _ground_truth_run(bag: BagReader, truth_topic: str, robot: Any, control: Any, scenario: str,
                      meta: dict[str, Any]) -> RunData:
    """The run against the ground truth (the module docstring's first mapping)."""
    truth = sorted(_first_per_stamp(_values_by_publish_time(
        bag, truth_topic, odometry_pose, odometry_pose_of_message)).items())
    currents = _values_by_publish_time(bag, find_topic(bag, "wheel_currents", "std_msgs/msg/Float64MultiArray"),
                                       float64_array, float64_array_of_message)
    volt_topic = find_topic(bag, "wheel_voltages", "std_msgs/msg/Float64MultiArray", False)
    applied = volt_topic is None  # a cmd_vel run: the plant's PI voltages, paired with a tick as its currents
    voltages = _values_by_publish_time(bag, volt_topic or _applied_voltages_topic(bag), float64_array,
                                       float64_array_of_message)
    odom = _first_per_stamp(_values_by_publish_time(bag, find_topic(bag, "odom", "nav_msgs/msg/Odometry", False),
                                                    odometry_pose, odometry_pose_of_message))
    previews = _first_per_stamp(_values_by_publish_time(
        bag, find_topic(bag, "reference_preview", "trajectory_msgs/msg/MultiDOFJointTrajectory", False),
        preview_start, preview_start_of_message))
    diags = _first_per_stamp([item for item in _values_by_publish_time(
        bag, find_topic(bag, "diagnostics", "diagnostic_msgs/msg/DiagnosticArray", False), read_controller_diagnostics,
        controller_diagnostics_of_message) if item[1][1] is not None])
    path_reference = _path_reference(bag)

    cur_t = [p for p, _ in currents]
    volt_t = [p for p, _ in voltages]
    truth_publish = [p for _, (p, _) in truth]
    rows: list[tuple] = []
    for k, (stamp, (publish, pose)) in enumerate(truth):
        next_publish = truth_publish[k + 1] if k + 1 < len(truth) else None
        current = _first_after(cur_t, currents, publish, next_publish)
        diag = diags.get(stamp)
        if applied:
            voltage = _first_after(volt_t, voltages, publish, next_publish)
        elif diag is not None:
            i = bisect_left(volt_t, diag[0]) - 1
            voltage = voltages[i][1] if i >= 0 else None
        else:
            after = odom[stamp][0] if stamp in odom else publish
            voltage = _first_after(volt_t, voltages, after, next_publish)
        if stamp in previews and previews[stamp][1] is not None:
            reference = previews[stamp][1]
        else:
            reference = path_reference(stamp)
        if current is None or voltage is None or reference is None or len(current) != 3 or len(voltage) != 3:
            continue
        rows.append((stamp, pose, reference, current, voltage, diag[1] if diag else None,
                     odom[stamp][1] if stamp in odom else None))
    if not rows:
        raise BagError(f"{bag.path}: no control tick with pose, reference, currents and voltages in the recording")
    t0 = rows[0][0]
    pose = np.array([r[1] for r in rows])
    reference = np.array([r[2] for r in rows])
    odometry = np.array([r[6] for r in rows]) if all(r[6] is not None for r in rows) else None
    for series in (pose, reference) if odometry is None else (pose, reference, odometry):
        series[:, 2] = np.unwrap(series[:, 2])
    flags: dict[str, np.ndarray] = {}
    compute = None
    if all(r[5] is not None for r in rows):
        for name in ("saturated", "infeasible"):
            flags[name] = np.array([r[5].get(name) == "true" for r in rows])
        compute = np.array([float(r[5]["compute_time_ms"]) * 1e-3 for r in rows])
    return RunData(
        scenario=scenario,
        t=np.array([(r[0] - t0) * 1e-9 for r in rows]),
        pose=pose,
        reference=reference,
        currents=np.array([r[3] for r in rows]),
        voltages=np.array([r[4] for r in rows]),
        control_period_s=control.period_s,
        horizon=control.horizon,
        nominal_current_a=robot.nominal_current_a,
        supply_voltage_v=robot.supply_voltage_v,
        flags=flags,
        compute_time_s=compute,
        odometry=odometry,
        meta={**meta, "truth": "ground_truth", "ticks_dropped": len(truth) - len(rows)},
    )


def _path_reference(bag: BagReader) -> Callable[[int], tuple[float, float, float] | None]:
    """The reference at a stamp [ns] from the last ``reference_path`` (linear between its poses; None outside)."""
    path = by_publish_time(bag, find_topic(bag, "reference_path", "nav_msgs/msg/Path", False))
    poses = path[-1][1].poses if path else []
    if not poses:
        return lambda stamp: None
    path_t = np.array([stamp_ns(p.header.stamp) for p in poses], dtype=np.int64)
    path_ref = np.array([(p.pose.position.x, p.pose.position.y, yaw(p.pose.orientation)) for p in poses])
    path_ref[:, 2] = np.unwrap(path_ref[:, 2])

    def at(stamp: int) -> tuple[float, float, float] | None:
        if not path_t[0] <= stamp <= path_t[-1]:
            return None
        x, y, theta = (float(np.interp(stamp, path_t, path_ref[:, j])) for j in range(3))
        return x, y, theta
    return at


def _preview_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A preview's points: poses, velocities and accelerations (x, y, theta), each (points, 3), zeros where a
    point has no derivatives; None when a point has no transform.
    """
    if not msg.points or not all(point.transforms for point in msg.points):
        return None

    def triple(twists: Any) -> tuple[float, float, float]:
        return (twists[0].linear.x, twists[0].linear.y, twists[0].angular.z) if twists else (0.0, 0.0, 0.0)
    poses = np.array([(p.transforms[0].translation.x, p.transforms[0].translation.y, yaw(p.transforms[0].rotation))
                      for p in msg.points])
    poses[:, 2] = np.unwrap(poses[:, 2])
    return (poses, np.array([triple(p.velocities) for p in msg.points]),
            np.array([triple(p.accelerations) for p in msg.points]))


def _preview_reference(bag: BagReader, control: ControlParams) -> Callable[[int], tuple[float, float, float] | None]:
    """The reference the controller had at a stamp [ns]: the newest ``reference_preview`` stamped at or before it
    (within its span of N Ts), moved to the stamp as the controller moves it (`reference.trajectories.preview_at`:
    a longer preview's row of the periods elapsed, to second order from there); the ``reference_path`` otherwise.
    """
    read: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray] | None] = {}
    for _, msg in by_publish_time(bag, find_topic(bag, "reference_preview",
                                                  "trajectory_msgs/msg/MultiDOFJointTrajectory", False)):
        read.setdefault(stamp_ns(msg.header.stamp), _preview_arrays(msg))
    previews = {stamp: arrays for stamp, arrays in read.items() if arrays is not None}
    stamps = sorted(previews)
    path_reference = _path_reference(bag)
    period_ns = round(control.period_s * 1e9)
    span_ns, points = control.horizon * period_ns, control.horizon + 1

    def at(stamp: int) -> tuple[float, float, float] | None:
        i = bisect_right(stamps, stamp) - 1
        if i < 0 or stamp - stamps[i] > span_ns:
            return path_reference(stamp)
        positions = preview_at(stamp, stamps[i], *previews[stamps[i]], period_ns, points)[0]
        return tuple(positions[0].tolist())
    return at


def _latest_before(times: list[int], items: list[tuple[int, Any]], end: int | None) -> Any:
    """The value of the newest item published before `end` (all items for None), None if there is none."""
    i = (bisect_left(times, end) if end is not None else len(items)) - 1
    return items[i][1] if i >= 0 else None


def _twist(msg: Any) -> tuple[float, float, float]:
    return (msg.linear.x, msg.linear.y, msg.angular.z)


def _odometry_run(bag: BagReader, robot: Any, control: Any, scenario: str, meta: dict[str, Any]) -> RecordedRun:
    """The run as odometry sees it (a recording without ground truth; the module docstring's second mapping)."""
    samples = _values_by_publish_time(bag, find_topic(bag, "odom", "nav_msgs/msg/Odometry"), odometry_pose,
                                      odometry_pose_of_message)
    last: dict[int, tuple[float, float, float]] = {}  # stamp -> the pose of its last message
    begins: dict[int, int] = {}  # stamp -> publish time of its first message
    for publish, (stamp, pose) in samples:
        last[stamp] = pose
        begins.setdefault(stamp, publish)
    stamps = sorted(last)
    float_topic = "std_msgs/msg/Float64MultiArray"
    series = {}  # name -> (publish times, items) of the optional series
    for name, topics in (("currents", ("wheel_currents",)), ("voltages", ("wheel_voltages", "applied_voltages"))):
        topic = next((t for t in (find_topic(bag, n, float_topic, False) for n in topics) if t is not None), None)
        if topic is not None:
            items = _values_by_publish_time(bag, topic, float64_array, float64_array_of_message)
            series[name] = ([p for p, _ in items], items)
    cmd_topic = find_topic(bag, "cmd_vel", "geometry_msgs/msg/Twist", False)
    commands = [(p, _twist(m)) for p, m in by_publish_time(bag, cmd_topic)] if "currents" not in series else []
    command_t = [p for p, _ in commands]
    reference_at = _preview_reference(bag, control)
    rows: list[tuple] = []
    for k, stamp in enumerate(stamps):
        end = begins[stamps[k + 1]] if k + 1 < len(stamps) else None
        point = reference_at(stamp)
        values = {name: _latest_before(times, items, end) for name, (times, items) in series.items()}
        if point is None or any(v is None or len(v) != 3 for v in values.values()):
            continue
        twist = _latest_before(command_t, commands, end) if cmd_topic is not None else None
        rows.append((stamp, last[stamp], point, values.get("currents"), values.get("voltages"),
                     twist or (0.0, 0.0, 0.0)))
    if not rows:
        raise BagError(f"{bag.path}: no odometry tick with a reference (reference_preview or reference_path)"
                       + (", currents" if "currents" in series else "")
                       + (" and voltages" if "voltages" in series else "") + " in the recording")
    t0 = rows[0][0]
    pose, reference = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
    for angles in (pose, reference):
        angles[:, 2] = np.unwrap(angles[:, 2])
    zeros = np.zeros((len(rows), 3))
    twist = np.array([r[5] for r in rows]) if "currents" not in series and cmd_topic is not None else None
    run = RunData(
        scenario=scenario,
        t=np.array([(r[0] - t0) * 1e-9 for r in rows]),
        pose=pose,
        reference=reference,
        currents=np.array([r[3] for r in rows]) if "currents" in series else zeros,
        voltages=np.array([r[4] for r in rows]) if "voltages" in series else zeros,
        control_period_s=control.period_s,
        horizon=control.horizon,
        nominal_current_a=robot.nominal_current_a,
        supply_voltage_v=robot.supply_voltage_v,
        meta={**meta, "truth": "odometry", "ticks_dropped": len(stamps) - len(rows)},
    )
    wheels = None if twist is None else twist @ (MotorKinematics(robot).W0 / robot.gear_ratio).T
    return RecordedRun(run, "currents" in series, "voltages" in series, twist, wheels)


_CURRENT_KEYS = ("peak_current_a", "peak_current_after_settle_a", "samples_above_nominal_current",
                 "current_within_nominal")
_VOLTAGE_KEYS = ("peak_voltage_v", "voltage_within_supply")


@dataclass(frozen=True)
class Report:
    """What `write_report` wrote: the metrics (as in metrics.json), the figures' paths, the truth it used."""

    metrics: dict[str, Any]
    figures: list[Path]
    truth: str


def write_report(
    bag: BagReader | str | os.PathLike,
    out_dir: str | os.PathLike,
    params_file: str | os.PathLike | None = None,
    settle_time_s: float = 1.0,
    plots: bool = True,
) -> Report:
    """Write ``out_dir/metrics.json`` and (with `plots`) the figures of a recorded run.

    Uses `results.compute_metrics` / `results.write_metrics` and `plots.write_plots`, the same code as
    ``simulate`` and ``run``. The metrics name the truth they are measured against (``truth``:
    ``"ground_truth"`` or ``"odometry"``, `recorded_run`); without ground truth they also hold ``timing``, the
    odometry's and commands' timing (`odometry_timing.odometry_timing`), and the current (voltage) metrics are
    None where the recording has no currents (voltages). A run with plans also gets ``link``, the link's figures
    as the recording shows them (`link_report.link_figures`).

    Raises
    ------
    BagError
        If the bag cannot be read or lacks the topics of a run.
    """
    if not isinstance(bag, BagReader):
        bag = BagReader(bag)
    recorded = recorded_run(bag, params_file)
    run = recorded.run
    out = Path(out_dir)
    metrics = compute_metrics(run, settle_time_s=settle_time_s)
    for present, keys in ((recorded.currents, _CURRENT_KEYS), (recorded.voltages, _VOLTAGE_KEYS)):
        if not present:  # zeros stood in for the series: no figure of it
            metrics.update(dict.fromkeys(keys))
    metrics["truth"] = recorded.truth
    lockstep = find_topic(bag, "clock", "rosgraph_msgs/msg/Clock", False) is not None  # the lockstep plant's
    if recorded.truth == "odometry":
        metrics["timing"] = odometry_timing(bag, find_topic(bag, "odom", "nav_msgs/msg/Odometry"),
                                            find_topic(bag, "cmd_vel", "geometry_msgs/msg/Twist", False), lockstep)
    link = link_figures(bag, run.control_period_s, lockstep)
    if link is not None:  # a run with plans: the link it ran over, as the recording shows it
        metrics["link"] = link
    write_metrics(metrics, out / "metrics.json")
    figures: list[Path] = []
    if plots:
        from robotino_geom_mpc.offline.plots import write_plots  # matplotlib: imported only to draw

        commands = None if recorded.twist is None or recorded.wheel_speeds is None else \
            (recorded.twist, recorded.wheel_speeds)
        figures = write_plots(run, out, settle_time_s=settle_time_s, commands=commands, voltages=recorded.voltages)
    return Report(metrics, figures, recorded.truth)


def report_bag(
    bag: BagReader | str | os.PathLike,
    out_dir: str | os.PathLike,
    params_file: str | os.PathLike | None = None,
    settle_time_s: float = 1.0,
    plots: bool = True,
) -> dict[str, Any]:
    """`write_report`'s metrics (what ``run`` prints from)."""
    return write_report(bag, out_dir, params_file, settle_time_s, plots).metrics
