"""`robotino-geom-mpc identify`: excite the robot through cmd_vel, fit its chain, write the controller's parameters.

Against the emulated chain (default: the plant behind ``--chain NAME`` with ``--chain-set`` overrides) or,
with ``--ros``, against the driver's topics (``odom``, ``cmd_vel``; `ros.identify_io`). The excitation
and the fit are `control.chain_identification`'s; DIR/chain_params.yaml is a ROS 2 parameter file with the
identified ``chain.*`` in a ``robotino_controller`` section (checked by `params.files.check_parameter_files`
before it is reported), DIR/identify.json the fit. An excitation or fit that fails stops the robot and exits
with status 2 and the reason.
"""

from __future__ import annotations

import argparse
import json
from contextlib import AbstractContextManager
from pathlib import Path

import yaml

from . import VERBS, UsageError, seed_value
from robotino_geom_mpc.cli.simulate import add_chain_argument, chain_from_args

__all__ = ["add_parser", "run", "write_chain_file"]

CONTROLLER_NODE = "robotino_controller"


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the `identify` verb."""
    parser = sub.add_parser(
        "identify", help=VERBS["identify"],
        description="Drive a short, bounded excitation (about 6.6 s; at most 0.255 m/s, 1.03 rad/s, 1 m/s^2, "
        "6 rad/s^2) through cmd_vel, record odometry and fit the chain's round-trip dead time, acceleration ramps and "
        "speed-loop time constant. Writes DIR/chain_params.yaml (chain.* for the controller) and DIR/identify.json. "
        "Without --ros, against the emulated chain of --chain (robocup-logistics by default).",
    )
    add_chain_argument(parser)
    parser.add_argument("--params", type=Path, default=None,
                        help="ROS 2 parameter file of the emulated robot (default: Robotino 3 preset)")
    parser.add_argument("--seed", type=seed_value, default=0, metavar="N", help="seed of the emulated links")
    parser.add_argument("--ros", action="store_true",
                        help="identify a real robot: publish on cmd_vel and read odom over ROS 2 (the driver's "
                        "topics; clear space of 1.5 m around the robot; Ctrl-C stops it)")
    parser.add_argument("--odom-topic", default="odom", help="with --ros: the driver's odometry topic")
    parser.add_argument("--cmd-vel-topic", default="cmd_vel", help="with --ros: the driver's cmd_vel topic")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    parser.set_defaults(func=run)
    return parser


def write_chain_file(path: Path, values: dict, comment: str) -> Path:
    """The ``chain.*`` `values` as a ROS 2 parameter file for the controller node (nested like rcl reads it)."""
    tree: dict = {}
    for name, value in values.items():
        node = tree
        *parents, leaf = name.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    text = "".join(f"# {line}\n" for line in comment.splitlines())
    text += yaml.safe_dump({CONTROLLER_NODE: {"ros__parameters": tree}}, sort_keys=False)
    path.write_text(text)
    return path


def run(args: argparse.Namespace) -> int:
    """Excite, fit, write; returns the exit status."""
    from robotino_geom_mpc.control.chain_identification import Excitation, IdentifyError, RobotIO, fit_chain, \
        run_excitation
    from robotino_geom_mpc.model.driver_chain import chain_params
    from robotino_geom_mpc.params.files import check_parameter_files

    if args.chain is None:
        args.chain = "robocup-logistics"
    truth = chain_from_args(args)
    prior = chain_params(preset=args.chain)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create output folder {args.out}: {exc.strerror or exc}") from None
    excitation = Excitation()
    context: AbstractContextManager[RobotIO]
    if args.ros:
        from robotino_geom_mpc.ros.identify_io import ros_robot

        context = ros_robot(args.odom_topic, args.cmd_vel_topic)
        where = f"the robot on {args.cmd_vel_topic} / {args.odom_topic}"
    else:
        from contextlib import nullcontext

        from robotino_geom_mpc.model.chain_emulation import ChainEmulator, EmulatedRobot
        from robotino_geom_mpc.model.plant import RobotinoPlant
        from robotino_geom_mpc.params.files import load_params

        robot, _ = load_params(args.params)
        context = nullcontext(EmulatedRobot(ChainEmulator(RobotinoPlant(robot), truth, seed=args.seed)))
        where = f"the emulated {args.chain} chain"
    print(f"identify: {excitation.duration_s:g} s of excitation through {where}")
    try:
        with context as robot_io:
            recording = run_excitation(robot_io, excitation)
        fit = fit_chain(recording, prior, excitation)
    except IdentifyError as exc:
        raise UsageError(f"identify: {exc}") from None
    chain = fit.chain(prior)
    path = write_chain_file(
        args.out / "chain_params.yaml", {"chain.active": "enabled", **chain.values()},
        f"robotino-geom-mpc identify against {where}: round trip {1e3 * fit.round_trip_s:.1f} ms (fits "
        f"{1e3 * fit.round_trip_interval_s[0]:.0f}..{1e3 * fit.round_trip_interval_s[1]:.0f} ms), split evenly; the "
        f"rest from the {args.chain} preset.\nGive it to the controller: --ros-args --params-file THIS_FILE")
    check_parameter_files([path])
    report = {"round_trip_s": fit.round_trip_s, "round_trip_interval_s": list(fit.round_trip_interval_s),
              "ramp_translation_m_s2": fit.ramp_translation_m_s2, "ramp_rotation_rad_s2": fit.ramp_rotation_rad_s2,
              "speed_loop_time_constant_s": fit.speed_loop_time_constant_s,
              "rotation_time_constant_s": fit.rotation_time_constant_s, "twist_residual_rms": fit.residual_rms,
              "odometry_messages": int(len(recording.stamps)), "commands": int(len(recording.commands))}
    if not args.ros:
        report["truth"] = truth.values()
    (args.out / "identify.json").write_text(json.dumps(report, indent=2) + "\n")
    print(f"  round trip {1e3 * fit.round_trip_s:.1f} ms, ramps {fit.ramp_translation_m_s2:.3g} m/s^2 and "
          f"{fit.ramp_rotation_rad_s2:.3g} rad/s^2, speed loop {1e3 * fit.speed_loop_time_constant_s:.1f} ms "
          f"(rotation {1e3 * fit.rotation_time_constant_s:.1f} ms), residual {1e3 * fit.residual_rms:.2g} mm/s")
    print(f"  wrote {path} and {args.out / 'identify.json'}")
    return 0
