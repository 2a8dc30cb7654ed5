"""`robotino-geom-mpc simulate`: one offline closed-loop run, its metrics.json and figures.

Runs `simulation.run_scenario` (plant + controller + reference, no ROS) and
writes DIR/metrics.json, DIR/run.npz and the PNGs of `plots.write_plots` (none with ``--no-plots``).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

from robotino_geom_mpc.model.encoders import ODOMETRY_MODELS
from robotino_geom_mpc.network.link import MAX_DELAY_S, LinkError, LinkParams

from robotino_geom_mpc.scenarios import SCENARIOS, ScenarioError, get_scenario
from . import VERBS, UsageError, positive_float, seed_value

__all__ = ["add_chain_argument", "add_link_arguments", "add_no_plots_argument", "add_odometry_argument", "add_parser",
           "add_scenario_argument", "chain_from_args", "command_interface_from_args", "link_from_args", "run"]

SETTLE_TIME_S = 1.0


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `simulate` verb."""
    parser = sub.add_parser(
        "simulate",
        help=VERBS["simulate"],
        description="Run one scenario in the offline closed loop (plant + controller + reference) "
        "and write DIR/metrics.json, DIR/run.npz and the PNGs (paper Figs. 4-6, voltages, errors).",
    )
    add_scenario_argument(parser)
    parser.add_argument("--params", type=Path, default=None, help="ROS 2 parameter file (default: Robotino 3 preset)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: out/<scenario>)")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="simulated time [s] (default: the scenario's length)")
    parser.add_argument("--seed", type=seed_value, default=0, metavar="N",
                        help="seed of the odometry noise (default 0)")
    add_odometry_argument(parser)
    parser.add_argument("--current-limit", type=_current_limit, default=None, metavar="A",
                        help="wheel current limit of the closed-form mode [A] (control.current_limit_a; "
                        "0 = none, the paper's controller; default: the parameter file's)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_no_plots_argument(parser)
    add_command_interface_argument(parser)
    add_chain_argument(parser, implies_cmd_vel=True)
    parser.add_argument("--controller-chain", type=Path, default=None, metavar="FILE",
                        help="with --chain: the controller's chain.* from this parameter file (identify's "
                        "chain_params.yaml) instead of the true chain's")
    add_link_arguments(parser, "simulate")
    parser.set_defaults(func=run)
    return parser


def add_chain_argument(parser: argparse.ArgumentParser, *, implies_cmd_vel: bool = False) -> None:
    """The ``--chain NAME`` and ``--chain-set chain.NAME=VALUE`` options of `simulate`, `run`, `study` and `identify`.

    `implies_cmd_vel`: the verb has ``--command-interface`` (`simulate`, `run`), which ``--chain`` sets to cmd_vel
    (`command_interface_from_args`); the help says so only there.
    """
    from robotino_geom_mpc.model.driver_chain import CHAIN_PRESETS

    through = "implies --command-interface cmd_vel" if implies_cmd_vel else "the controller commands it by cmd_vel"
    parser.add_argument("--chain", choices=tuple(CHAIN_PRESETS), default=None,
                        help="put the real robot's driver and firmware chain between controller and plant "
                        f"(robocup-logistics: the ros2-robotino driver on a Robotino 3/4; {through}; "
                        "docs/robotino.md)")
    parser.add_argument("--chain-set", action="append", default=[], metavar="chain.NAME=VALUE",
                        help="override one chain parameter (repeatable), e.g. chain.link.delay_s=0.01")


def controller_chain_from_file(path: Path, preset: str):  # noqa: ANN201 - ChainParams, imported lazily
    """The controller's chain.* of a parameter file (`identify`'s), over `preset`; UsageError if bad."""
    from robotino_geom_mpc.model.driver_chain import ChainError, chain_params
    from robotino_geom_mpc.params.files import check_parameter_files, read_parameter_file

    check_parameter_files([path])
    values = read_parameter_file(path, "robotino_controller")
    try:
        return chain_params({k: v for k, v in values.items() if k.startswith("chain.") and k != "chain.active"},
                            preset, str(path))
    except ChainError as exc:
        raise UsageError(str(exc)) from None


def chain_from_args(args: argparse.Namespace):  # noqa: ANN201 - ChainParams, imported lazily
    """The `ChainParams` of ``--chain`` / ``--chain-set``, or None without ``--chain``; UsageError if bad."""
    from robotino_geom_mpc.model.driver_chain import ChainError, chain_params

    if args.chain is None:
        if args.chain_set:
            raise UsageError("--chain-set needs --chain")
        return None
    values = {}
    for item in args.chain_set:
        name, sep, text = item.partition("=")
        if not sep:
            raise UsageError(f"--chain-set wants chain.NAME=VALUE, got {item!r}")
        try:
            value = float(text)
        except ValueError:
            value = text
        values[name.strip()] = value
    try:
        return chain_params(values, args.chain)
    except ChainError as exc:
        raise UsageError(str(exc)) from None


_LINK_OPTIONS = (  # (option, LinkParams field, metavar, help)
    ("--link-delay-ms", "delay_s", "D", "fixed one-way delay D [ms]"),
    ("--link-jitter-ms", "jitter_s", "J", "plus a uniform jitter in [0, J] per packet [ms] (reorders packets)"),
    ("--link-loss", "loss", "P", "long-run loss probability P in [0, 1) (Gilbert-Elliott bursts)"),
    ("--link-burst", "burst_length", "B", "mean loss-burst length B [packets] (default 1: isolated losses; "
     "needs P <= B / (B + 1))"),
)
MAX_DELAY_MS = 1e3 * MAX_DELAY_S  # --link-delay-ms and --link-jitter-ms: `LinkParams`' range in the options' unit
# what runs over the link, per verb (the options' help)
LINK_LOOPS = {"simulate": "the offline loop", "study": "each offline run", "run": "the loop over DDS (the plant "
              "node emulates the link)"}


def _finite_float(text: str) -> float:
    """argparse type: a finite number (ranges are the link's to check, naming the option)."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def add_link_arguments(parser: argparse.ArgumentParser, verb: str) -> None:
    """The emulated radio link's options (each way) of `simulate`, `study` and `run`, and ``--no-compensation``."""
    group = parser.add_argument_group("radio link between the robot and the controller, each way "
                                      "(network.link; docs/howto/networked_control.md)")
    for option, _, metavar, text in _LINK_OPTIONS:
        group.add_argument(option, type=_finite_float, default=None, metavar=metavar,
                           help=f"{text}; any of these options runs {LINK_LOOPS[verb]} over the link "
                           "(default: the scenario's link, none but for wifi)")
    group.add_argument("--no-compensation", action="store_true",
                       help="over a link: the plain controller, each command acting when it arrives and held "
                       "(the uncompensated baseline) instead of the delay-compensating plans")


def link_from_args(args: argparse.Namespace) -> LinkParams | None:
    """The link of the ``--link-*`` options (the same each way), None when none is given.

    Raises
    ------
    UsageError
        For a value out of range, naming its option and in its unit (ms for the delay and the jitter).
    """
    delay, jitter, loss, burst = (getattr(args, option[2:].replace("-", "_")) for option, *_ in _LINK_OPTIONS)
    if delay is None and jitter is None and loss is None and burst is None:
        return None
    for option, value in (("--link-delay-ms", delay), ("--link-jitter-ms", jitter)):
        if value is not None and not 0.0 <= value <= MAX_DELAY_MS:
            raise UsageError(f"{option} must be in [0, {MAX_DELAY_MS:g}] ms, got {value:g}")
    if loss is not None and not 0.0 <= loss < 1.0:
        raise UsageError(f"--link-loss must be in [0, 1), got {loss:g}")
    if burst is not None and burst < 1.0:
        raise UsageError(f"--link-burst must be >= 1 packet, got {burst:g}")
    loss, burst = loss or 0.0, 1.0 if burst is None else burst
    if loss > burst / (burst + 1.0):
        raise UsageError(f"--link-loss {loss:g} needs --link-burst >= {loss / (1.0 - loss):g} (a loss P with bursts "
                         f"of B packets needs P <= B / (B + 1)), got {burst:g}")
    try:
        return LinkParams.from_ms(delay or 0.0, jitter or 0.0, loss, burst)
    except LinkError as exc:  # the checks above are LinkParams' own in the options' units: a guard only
        raise UsageError(f"--link-*: {exc}") from None


def _current_limit(text: str) -> float:
    """argparse type: a value of control.current_limit_a, checked against its spec."""
    from robotino_geom_mpc.params.specs import CONTROL_SPECS, ParamError, validate_value

    spec = next(s for s in CONTROL_SPECS if s.name == "control.current_limit_a")
    try:
        return validate_value(spec, float(text))
    except (ValueError, ParamError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _scenario_name(text: str) -> str:
    """argparse type: a name of the scenario registry; an unknown one is refused with the closest valid name."""
    try:
        return get_scenario(text).name
    except ScenarioError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_scenario_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--scenario NAME`` option of `simulate` and `run`: the choices and their help from the registry."""
    parser.add_argument("--scenario", required=True, type=_scenario_name, choices=tuple(SCENARIOS), metavar="NAME",
                        help="; ".join(f"{s.name}: {s.description}" for s in SCENARIOS.values()).replace("%", "%%"))


def add_odometry_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--odometry {ideal,encoders}`` option of `simulate` and `run`."""
    parser.add_argument("--odometry", choices=ODOMETRY_MODELS, default="ideal",
                        help="the plant's odometry: ideal (true pose plus the scenario's noise, true twist; default) "
                        "or encoders (dead reckoning from 2048-count motor encoders: drifts from the ground truth)")


def add_no_plots_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--no-plots`` option of `simulate`, `run` and `report`."""
    parser.add_argument("--no-plots", action="store_true",
                        help="write no figures, only the metrics (for scripts and batches of runs)")


def add_command_interface_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--command-interface {voltages,cmd_vel}`` option of `simulate` and `run` (`command_interface_from_args`)."""
    parser.add_argument("--command-interface", choices=("voltages", "cmd_vel"), default=None,
                        help="voltages: the controller's wheel voltages drive the motors (default); cmd_vel: its "
                        "base_link velocity is held by per-wheel PI speed loops, as on a Robotino driven by cmd_vel "
                        "(the default with --chain)")


def command_interface_from_args(args: argparse.Namespace, chain: object | None) -> str:
    """The command interface of ``--command-interface``; with ``--chain`` (`chain` not None) cmd_vel, the driver's.

    Raises
    ------
    UsageError
        For ``--chain`` with an explicit ``--command-interface voltages``.
    """
    if chain is None:
        return args.command_interface or "voltages"
    if args.command_interface == "voltages":
        raise UsageError("--chain drives the robot through the driver's cmd_vel: drop --command-interface voltages "
                         "(--chain implies --command-interface cmd_vel)")
    return "cmd_vel"


def _fmt(value: float | None, unit: str) -> str:
    return "n/a" if value is None else f"{value:.3g} {unit}"


def run(args: argparse.Namespace) -> int:
    """Run the scenario, write the outputs, print a summary; returns the exit status."""
    from robotino_geom_mpc.params.files import load_params
    from robotino_geom_mpc.offline.results import compute_metrics, save_run, write_metrics
    from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario

    chain = chain_from_args(args)
    command_interface = command_interface_from_args(args, chain)
    if chain is not None and args.odometry != "ideal":
        raise UsageError("--chain gives the firmware's odometry: use it with --odometry ideal")
    if args.controller_chain is not None and chain is None:
        raise UsageError("--controller-chain needs --chain")
    controller_chain = None if args.controller_chain is None else controller_chain_from_file(args.controller_chain,
                                                                                            args.chain)
    robot, control = load_params(args.params)
    link = link_from_args(args)
    if chain is not None and (link is not None or args.no_compensation):
        raise UsageError("--chain has its own link (chain.link.*, set by --chain-set), not --link-* or "
                         "--no-compensation")
    if args.current_limit is not None:
        control = replace(control, current_limit_a=args.current_limit)
    out = args.out if args.out is not None else Path("out") / args.scenario
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create output folder {out}: {exc.strerror or exc}") from None

    start = time.perf_counter()
    data = run_scenario(RunConfig(
        args.scenario, robot, control, duration_s=args.duration, seed=args.seed, progress=not args.no_progress,
        odometry=args.odometry, command_interface=command_interface, link_up=link, link_down=link,
        compensate=not args.no_compensation, chain=chain, controller_chain=controller_chain,
    ))
    wall_s = time.perf_counter() - start

    metrics = compute_metrics(data, settle_time_s=SETTLE_TIME_S)
    metrics["wall_time_s"] = wall_s
    metrics["realtime_factor"] = metrics["duration_s"] / wall_s
    write_metrics(metrics, out / "metrics.json")
    save_run(data, out / "run.npz")
    if args.no_plots:
        figures = []
    else:
        from robotino_geom_mpc.offline.plots import write_plots

        figures = write_plots(data, out, settle_time_s=SETTLE_TIME_S)

    m = metrics
    print(f"scenario {m['scenario']}: {m['duration_s']:.3g} s simulated in {wall_s:.3g} s")
    print(f"  position error after {SETTLE_TIME_S:g} s: rms {_fmt(m['rms_position_error_m'], 'm')}, "
          f"max {_fmt(m['max_position_error_m'], 'm')}")
    if args.odometry != "ideal":
        print(f"  in the odom frame ({args.odometry}): rms {_fmt(m['rms_position_error_odom_m'], 'm')}, "
              f"max {_fmt(m['max_position_error_odom_m'], 'm')}; drift from the truth at the end "
              f"{_fmt(m['odometry_drift_final_m'], 'm')}")
    print(f"  max |theta error|: {_fmt(m['max_abs_theta_error_rad'], 'rad')}")
    if chain is not None:
        print(f"  through the {args.chain} chain: measurement times reconstructed to "
              f"{1e3 * data.meta['measurement_time_error_rms_s']:.2g} ms rms "
              f"(max {1e3 * data.meta['measurement_time_error_max_s']:.2g} ms)")
    within = "within" if m["current_within_nominal"] else "ABOVE"
    print(f"  peak current {m['peak_current_a']:.3g} A ({within} nominal {m['nominal_current_a']:g} A), "
          f"peak voltage {m['peak_voltage_v']:.3g} V (supply {m['supply_voltage_v']:g} V)")
    if "link" in data.meta:
        print(f"  link: {_link_summary(data.meta['link'])}")
    print(f"  wrote {out / 'metrics.json'}, {out / 'run.npz'} and {len(figures)} figures")
    return 0


def _link_summary(meta: dict) -> str:
    """One line on the link of a run (`offline.networked.NetworkedLoop.meta`)."""
    up, down = meta["up"], meta["down"]
    text = (f"up {up['lost']}/{up['sent']} lost, down {down['lost']}/{down['sent']} lost; "
            + ("compensated" if meta["compensated"] else "uncompensated"))
    c = meta.get("controller")
    if c and c["round_trip_mean_s"] is not None:
        text += (f": round trip {1e3 * c['round_trip_mean_s']:.3g} ms mean, {1e3 * c['round_trip_jitter_s']:.3g} ms "
                 f"std, lead {c['lead_periods']} periods, {c['plans_lost']} plans lost, "
                 f"{c['exhausted_periods']} periods without a plan")
    return text
