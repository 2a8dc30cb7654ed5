"""`robotino-geom-mpc run`: the closed loop over DDS, one process per node, recorded, with metrics and figures.

Starts the recorder (unless ``--no-record``), the trajectory, the controller,
the plant simulator and the robot description publisher (URDF, wheels' TF)
as separate processes (``python -m MODULE --ros-args ...``, each in its own
process group, output in DIR/logs/), waits for the
plant to end the run (it knows the duration; its timing report, written
once every reader has its samples, marks the end), stops every node (SIGINT, then
SIGTERM and SIGKILL after a grace period; also on Ctrl-C or when a node
fails, which is reported with its stderr tail and exit status 1): the loop's
other nodes first, the recorder once they are gone; and writes DIR/metrics.json
and the figures from the recording (DIR/bag) through
`recording.report.report_bag`, the code behind ``report``, as soon as the
recorder has closed the bag (while its process exits).

In ``--lockstep`` (the default) the plant owns /clock and waits, before tick
0, for every subscription of the loop and of the recorder, so the recording
holds the whole run; the metrics then equal those of ``simulate`` on the same
scenario and parameters. With ``--goals FILE`` (scenario ``goals``) a goal sender
(`nodes.goal_sender`) publishes the file's goals and paths over DDS. Each node gets its scenario's overrides
(`scenarios.node_parameters`): e.g. in ``robustness`` the controller a
mismatched model and the plant odometry noise. With ``--command-interface cmd_vel`` the controller sends
twists on cmd_vel, the plant holds them with its wheel-speed PI loops, and the metrics' voltages are those
loops' (the plant's ``applied_voltages``). ``--chain NAME`` (with ``--realtime``; it implies ``--command-interface
cmd_vel``) puts the real robot's driver + firmware chain in the plant node and has the controller control through
it (``chain.active``; `robotino_sim_node.chain_driver`, `loop.controller_loop`).
With ``--foxglove PORT`` the live view (`recording.live_view_node`) starts first and the loop once its server is
up, so a Foxglove client connected by then sees the run from its first odometry.

``--robots N``: a fleet of N robots (namespaces ``robot1`` .. ``robotN``, `ros.fleet`), the same scenario each,
in three processes (`nodes.fleet_trajectory_node`, `nodes.fleet_controller_node`,
`robotino_sim_node.fleet_plant_node`: one node per robot in each) and one recorder: the whole fleet in one bag
(DIR/bag); each robot's metrics and figures from its namespace in it (`BagReader.in_namespace`) in
DIR/robot<k>/, and the fleet plant's timing in DIR/timing.json (per robot its timing report: ``ticks``,
``missed``, ...). In lockstep the fleet shares one /clock, so each robot's metrics equal a single robot's run.

Over a radio link (``--link-delay-ms D --link-jitter-ms J --link-loss P --link-burst B``, each way, or the
``wifi`` scenario's own link) the plant emulates it (``link.up.*`` / ``link.down.*``: everything it publishes
reaches the controller and the recorder when the link delivers it; commands and plans reach it so), the
controller sends delay-compensated plans and the plant applies them and reports what it applied
(``command_applied``; ``--no-compensation``: plain commands acting on arrival, the baseline). The recording then
holds what the controller received and when, and what the robot applied: ``regress`` replays the plans, and the
metrics get the link's measured figures (`recording.link_report`).
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from robotino_geom_mpc.scenarios import SCENARIOS
from . import VERBS, UsageError, positive_float, positive_int, seed_value
from robotino_geom_mpc.cli.simulate import add_chain_argument, add_command_interface_argument, add_link_arguments, \
    add_no_plots_argument, add_odometry_argument, add_scenario_argument, chain_from_args, command_interface_from_args, \
    link_from_args

if TYPE_CHECKING:
    from robotino_geom_mpc.system.processes import NodeGroup, NodeProcess

__all__ = ["add_parser", "run"]

GRACE_S = 5.0
# the recorder's: its drain limit (recorder_node.DRAIN_LIMIT_S, 60 s: a recorder behind the loop drains at stop)
# and the bag's close, before SIGTERM (then SIGKILL, which would lose the bag's summary)
RECORDER_GRACE_S = 70.0
BAG_CLOSE_POLL_S = 0.005  # how often the stop looks for the recorder's closed bag
RUN_END_POLL_S = 0.01  # how often `run` looks for the plant's timing report (the end of the run)
# imported in a thread while the nodes start and run (the cores idle during discovery and the settle)
REPORT_MODULES = ("robotino_geom_mpc.recording.bag_reader", "robotino_geom_mpc.recording.report",
                  "robotino_geom_mpc.cli.reindex", "rosbags.typesys.stores.ros2_jazzy")  # the last: the bag's types
GOALS_SETTLE_S = 3.0  # --goals: the run goes on this long after the last motion ends (the loop settles)
CHAIN_PI_RATE_HZ = 200.0  # --chain: the plant's wheel PI loops' rate over DDS
LIVE_VIEW_START_S = 60.0  # --foxglove: the live view serves within this (imports, DDS participant, server)
LIVE_VIEW_POLL_S = 0.05
LIVE_VIEW_READY = "Foxglove live view on ws://"  # what the live view node logs once its server is up
REALTIME_START_S = 2.0  # realtime: the reference starts this much after the first odometry (start_settle_s + discovery)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `run` verb."""
    parser = sub.add_parser(
        "run",
        help=VERBS["run"],
        description="Run one scenario as ROS 2 nodes over DDS, record it, and write DIR/metrics.json "
        "and the figures from the recording.",
    )
    add_scenario_argument(parser)
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--lockstep", dest="lockstep", action="store_true", default=True,
                      help="the plant drives /clock, one control period per command (default; deterministic)")
    mode.add_argument("--realtime", dest="lockstep", action="store_false",
                      help="wall-clock timers at the control rate")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="run length [s] (default: the scenario's length)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: out/run-<scenario>)")
    parser.add_argument("--params", type=Path, default=None, help="ROS 2 parameter file (default: Robotino 3 preset)")
    parser.add_argument("--seed", type=seed_value, default=0, metavar="N",
                        help="seed of the odometry noise (default 0)")
    add_odometry_argument(parser)
    add_command_interface_argument(parser)
    add_chain_argument(parser, implies_cmd_vel=True)
    add_link_arguments(parser, "run")
    parser.add_argument("--plans", action="store_true",
                        help="the controller sends delay-compensated plans and the plant applies them at their times "
                        "even without a link (over a link they are the default)")
    parser.add_argument("--no-record", action="store_true", help="no recording (and so no metrics or figures)")
    add_no_plots_argument(parser)
    parser.add_argument("--goals", type=Path, default=None, metavar="FILE",
                        help="scenario goals: a goal file (YAML/JSON, e.g. config/goals_example.yaml) whose goals "
                        "and paths a sender publishes on goal_pose and plan; the run lasts until they end + 3 s")
    parser.add_argument("--robots", type=positive_int, default=None, metavar="N",
                        help="a fleet of N robots (robot1 .. robotN) through one controller, one plant and one "
                        "trajectory process; DIR/robot<k>/metrics.json and DIR/timing.json")
    parser.add_argument("--foxglove", type=_port, nargs="?", const=8765, default=None, metavar="PORT",
                        help="serve the run's topics live to Foxglove on ws://localhost:PORT (default 8765; needs "
                        "the [viz] extra); the loop starts once it serves; a lockstep run then goes at real time")
    parser.set_defaults(func=run)
    return parser


def _port(text: str) -> int:
    """A TCP port (1..65535) for argparse."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is not in 1..65535")
    return port


def _fleet_problem(args: argparse.Namespace) -> str | None:
    """Why `args` cannot run as a fleet (`--robots`), None when they can."""
    if args.chain is not None or args.goals is not None or args.foxglove is not None or args.plans:
        return "--robots runs without --chain, --goals, --foxglove and --plans"
    if link_from_args(args) is not None:  # (a scenario's own link: the fleet plant refuses it at its start)
        return "--robots runs without a link (a fleet's lockstep plants share one clock)"
    return None


def _raise_interrupt(*_: object) -> None:
    raise KeyboardInterrupt


def _import_in_background(modules: tuple[str, ...]) -> threading.Thread:
    """Import `modules` in a daemon thread (matplotlib, rosbags: ~1 s of CPU the report would wait for).

    The thread runs at the lowest CPU priority (Linux: a thread's own nice value), so the imports take the
    cores the nodes leave idle (discovery, the start handshake) instead of slowing the nodes' start and loop.
    """

    def load() -> None:
        if hasattr(os, "setpriority"):
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)  # this thread only
            except OSError:
                pass
        for name in modules:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - the report's own import raises it again, in the main thread
                return

    thread = threading.Thread(target=load, name="report-imports", daemon=True)
    thread.start()
    return thread


def _stopped_cleanly(group: NodeGroup, node: NodeProcess, grace_s: float) -> None:
    """Stop `node` (`NodeGroup.stop_node`); `NodeFailed` unless it exits with 0 (or by SIGINT)."""
    from robotino_geom_mpc.system.processes import NodeFailed

    if group.stop_node(node, grace_s) not in (0, -signal.SIGINT):
        raise NodeFailed(f"{node.name} did not stop cleanly:\n{node.stderr_tail()}")


def _close_recording(group: NodeGroup, recorder: NodeProcess, bag: Path) -> None:
    """SIGINT the recorder and wait until its bag is closed: metadata.yaml, the last file `BagWriter.close`
    writes, is there, or the recorder exits (its status is checked then). A recorder that closed its bag still
    exits (Fast DDS alone sleeps 0.1 s in its participant factory's destructor) while the report reads the bag;
    `run` checks its status after the report.
    """
    recorder.popen.send_signal(signal.SIGINT)
    ended = group.wait(recorder, RECORDER_GRACE_S, done=(bag / "metadata.yaml").exists, poll_s=BAG_CLOSE_POLL_S)
    if not ended or recorder.popen.poll() is not None:  # exited: its status now; hung: SIGTERM, then SIGKILL
        _stopped_cleanly(group, recorder, GRACE_S)


def _check_viz() -> None:
    """`UsageError` naming the install line when the Foxglove SDK (the [viz] extra) is missing."""
    import importlib.util

    if importlib.util.find_spec("foxglove") is None:
        raise UsageError("--foxglove needs the Foxglove SDK: pip install 'robotino_geom_mpc[viz]' "
                         "(or pip install foxglove-sdk)")


def _start_live_view(group: NodeGroup, argv: list[str]) -> NodeProcess:
    """Start the live view node and wait until it logs that it serves (`NodeFailed` if it does not)."""
    from robotino_geom_mpc.system.processes import NodeFailed

    view = group.start("live_view_node", argv)

    def serving() -> bool:  # rclpy logs to stderr
        return LIVE_VIEW_READY in view.stderr_path.read_text(errors="replace")

    if not group.wait(view, LIVE_VIEW_START_S, done=serving, poll_s=LIVE_VIEW_POLL_S) or view.popen.poll() is not None:
        raise NodeFailed(f"the live view did not serve within {LIVE_VIEW_START_S:g} s:\n{view.stderr_tail()}")
    return view


def _goals_duration(args: argparse.Namespace, params_file: Path) -> float:
    """The run length for a goal file: its motions planned offline with the trajectory node's limits, + 3 s."""
    from robotino_geom_mpc.reference.goal_file import LIMIT_DEFAULTS, load_goal_file, motion_limits, planned_end_s
    from robotino_geom_mpc.reference.goal_motion import GoalError
    from robotino_geom_mpc.params.specs import ParamError
    from robotino_geom_mpc.params.files import read_parameter_file

    if args.scenario != "goals":
        raise UsageError(f"--goals needs --scenario goals, not {args.scenario!r}")
    try:
        values = {**LIMIT_DEFAULTS, **read_parameter_file(params_file, "robotino_trajectory")}
        end = planned_end_s(load_goal_file(args.goals), motion_limits(values))
    except (GoalError, ParamError) as exc:
        raise UsageError(str(exc)) from None
    return end + GOALS_SETTLE_S + (0.0 if args.lockstep else REALTIME_START_S)


def run(args: argparse.Namespace) -> int:
    """Run the nodes, stop them, write the metrics and figures; returns the exit status."""
    from robotino_geom_mpc.params.files import load_params
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import TIMING_REPORT, NodeFailed, NodeGroup, fleet_arguments, \
        node_arguments, robot_names

    fleet = args.robots is not None
    if fleet:
        problem = _fleet_problem(args)
        if problem is not None:
            raise UsageError(problem)
    chain = chain_from_args(args)
    command_interface = command_interface_from_args(args, chain)
    overrides: dict = {}
    if chain is not None:  # the plant behind the driver chain, the controller through it (both: chain.active)
        if args.lockstep:
            raise UsageError("--chain needs --realtime (the driver's loop and the firmware's tick run on the wall "
                             "clock)")
        values = {"chain.active": "enabled", **chain.values()}
        # the PI loops at 200 Hz (5 samples a tick, 1 kHz offline): the emulation keeps up with the wall clock
        # (the recorder stores the controller's chain in the bag, `node_arguments`: regress replays it)
        overrides = {"plant_node": {**values, "wheel_pi.rate_hz": CHAIN_PI_RATE_HZ}, "controller_node": dict(values)}
    link = link_from_args(args)
    params_file = (args.params or default_params_file()).resolve()
    _, control = load_params(params_file)
    duration = args.duration if args.duration is not None else SCENARIOS[args.scenario].duration_s
    if args.goals is not None:
        duration = _goals_duration(args, params_file) if args.duration is None else duration
    out = args.out if args.out is not None else Path("out") / f"run-{args.scenario}"
    bag = None if args.no_record else out.resolve() / "bag"
    report = out.resolve() / ("timing.json" if fleet else Path("logs") / TIMING_REPORT)
    try:
        out.mkdir(parents=True, exist_ok=True)
        if bag is not None and bag.exists():
            shutil.rmtree(bag)  # the previous run's recording
        report.unlink(missing_ok=True)  # and its plant's timing report
    except OSError as exc:
        raise UsageError(f"cannot prepare output folder {out}: {exc.strerror or exc}") from None

    node_args = fleet_arguments(args.scenario, params_file, duration, args.lockstep, args.robots, args.seed, bag,
                                odometry=args.odometry, command_interface=command_interface,
                                overrides={"plant_node": {"timing_report": str(report)}}) if fleet else \
        node_arguments(args.scenario, params_file, duration, args.lockstep, args.seed, bag,
                               odometry=args.odometry, command_interface=command_interface, link=link,
                               plans=False if args.no_compensation else (True if args.plans else None),
                               goals_file=None if args.goals is None else args.goals.resolve(),
                               overrides={**overrides, "plant_node": {**overrides.get("plant_node", {}),
                                                                      "timing_report": str(report)}},
                               live_view_port=args.foxglove)
    if args.foxglove is not None:
        _check_viz()
    mode = "lockstep" if args.lockstep else "realtime"
    robots = f", {args.robots} robots" if fleet else ""
    print(f"run {args.scenario} over DDS ({mode}{robots}, {duration:g} s, Ts = {control.period_s:g} s); logs in "
          f"{out / 'logs'}")
    plant = "fleet_plant_node" if fleet else "plant_node"
    if args.foxglove is not None:
        print(f"  live view: connect Foxglove to ws://localhost:{args.foxglove}")
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    group = NodeGroup(log_dir=out / "logs")
    start = time.monotonic()
    try:
        nodes = {}
        if args.foxglove is not None:  # serving before the loop starts: a client that connects at once sees it all
            nodes["live_view_node"] = _start_live_view(group, node_args.pop("live_view_node"))
        nodes.update({name: group.start(name, argv) for name, argv in node_args.items()})
        if bag is not None:
            _import_in_background(REPORT_MODULES)
        # the plant ends the run; lockstep may be slower than real time on a loaded machine
        limit = duration + 60.0 if not args.lockstep else 60.0 + 20.0 * duration
        # the end: the plant's timing report (written once every reader has acknowledged its samples), or its exit
        if not group.wait(nodes[plant], limit, done=report.exists, poll_s=RUN_END_POLL_S):
            print(f"robotino-geom-mpc run: error: the run did not end within {limit:g} s", file=sys.stderr)
            return 1
        ended = time.monotonic()
        group.check()
        # every reader has the plant's samples, and each other node waits for its readers' acknowledgements on
        # SIGINT before it exits (`ros.spin.run_node`): once they are gone, the recorder holds every message
        others = [name for name in nodes if name not in (plant, "recorder_node")]
        for name in others:
            nodes[name].popen.send_signal(signal.SIGINT)  # all at once; `stop_node` escalates per node
        for name in [*others, plant]:  # the plant ends by itself (a SIGINT in its exit is ignored)
            _stopped_cleanly(group, nodes[name], GRACE_S)
        if bag is not None:
            _close_recording(group, nodes["recorder_node"], bag)
        stopped = time.monotonic()
        print(f"  {duration:g} s run in {stopped - start:.1f} s wall: {ended - start:.1f} s until the plant ended "
              f"(startup, discovery, the loop), {stopped - ended:.1f} s to stop the nodes and close the recording")
        if bag is None:
            print("  not recorded (--no-record): no metrics or figures")
            return 0
        from robotino_geom_mpc.recording.bag_reader import BagReader, damage_report
        from robotino_geom_mpc.recording.bagfile import BagError
        from robotino_geom_mpc.recording.report import report_bag
        from robotino_geom_mpc.cli.reindex import warn_damage

        try:
            reader = BagReader(bag)
            warn_damage("run", damage_report(reader))
            if fleet:
                fleet_metrics = {ns: report_bag(reader.in_namespace(ns), out / ns, params_file, plots=not args.no_plots)
                                 for ns in robot_names(args.robots)}
            else:
                metrics = report_bag(reader, out, params_file, plots=not args.no_plots)
        except BagError as exc:
            print(f"robotino-geom-mpc run: error: {exc}", file=sys.stderr)
            return 1
        _stopped_cleanly(group, nodes["recorder_node"], RECORDER_GRACE_S)  # it exits while the report runs
    except NodeFailed as exc:
        print(f"robotino-geom-mpc run: error: {exc}", file=sys.stderr)
        return 1
    finally:
        group.stop(GRACE_S)
        signal.signal(signal.SIGTERM, previous)
    if fleet:
        _print_fleet(fleet_metrics, report, out)
        return 0
    print(f"  position error after settle: rms {metrics['rms_position_error_m']:.3g} m, "
          f"max {metrics['max_position_error_m']:.3g} m; peak current {metrics['peak_current_a']:.3g} A, "
          f"peak voltage {metrics['peak_voltage_v']:.3g} V")
    if metrics.get("link") is not None:
        from robotino_geom_mpc.recording.link_report import link_line

        print(f"  link: {link_line(metrics['link'])}")
    if metrics.get("rms_position_error_odom_m") is not None:
        print(f"  in the odom frame: rms {metrics['rms_position_error_odom_m']:.3g} m; drift from the truth at the "
              f"end {metrics['odometry_drift_final_m']:.3g} m")
    print(f"  wrote {out / 'metrics.json'}{'' if args.no_plots else ' and the figures'} in "
          f"{time.monotonic() - stopped:.1f} s; recording in {bag}")
    return 0


def _print_fleet(metrics: dict[str, dict], timing: Path, out: Path) -> None:
    """Per robot: the tracking figures and the ticks the plant counted (answered, missed)."""
    import json

    ticks = json.loads(timing.read_text())
    for namespace, m in metrics.items():
        t = ticks.get(namespace) or {}
        print(f"  {namespace}: rms {m['rms_position_error_m']:.3g} m, max {m['max_position_error_m']:.3g} m, peak "
              f"current {m['peak_current_a']:.3g} A; ticks {t.get('ticks')}, missed {t.get('missed')}")
    total = sum(t.get("ticks") or 0 for t in ticks.values())
    missed = sum(t.get("missed") or 0 for t in ticks.values())
    if missed:  # realtime only: a lockstep fleet misses none
        print(f"  the fleet missed {missed} of {total} ticks ({100 * missed / total:.2g} %): more robots than this "
              "machine keeps at the control rate (docs/howto/several_robots.md, Capacity)")
    print(f"  wrote {out}/robot<k>/metrics.json and {timing}")
