"""Offline closed loop (Fig. 3): reference -> controller -> simulated Robotino, one control period at a time.

This engine is the reference the ROS 2 nodes reproduce (to 1e-6): it drives the same two loops as the nodes, the
controller node's protocol (`loop.controller_loop.ControllerLoop`, lockstep) and the plant node's robot
(`loop.robot_loop.RobotLoop`), on one simulated clock. Each tick k (t_k = k Ts, k = 0 .. n-1) does, in this order:

1. measure: ``pose, twist = RobotLoop.measure()`` (the pose plus Gaussian noise drawn from the run's seeded
   generator, all ticks' at once, and the noise-free body-frame twist; with ``odometry="encoders"`` the pose
   integrated from the wheel-encoder counts plus the same noise, and the encoder twist: `encoders`);
2. the controller's inputs as the nodes send them (`offline.lockstep`): the preview of tick k (the reference's
   pose, velocity and acceleration at t_k + j Ts, j = 0 .. N, eq. 54, sampled for the whole run at once), then
   the odometry stamped t_k; in process both carry the yaw as it is (`loop.events.PlanarPreview`,
   `PlanarOdometry`), not as the quaternion of the messages;
3. the loop's answer (`offline.lockstep.LockstepController`): the checks, X of eq. 2, and at t = 0 robot and
   reference started together, then ``MotionController.step(X, Y_d)`` (three MPCs -> T(theta) -> inverse drive);
   its voltages, or with ``cmd_vel`` its base_link velocity for the next period;
4. record t_k, the true pose, the measured pose, the reference at t_k and the step's flags;
5. ``RobotLoop.drive(command)`` (the plant over Ts, or the wheels' PI speed loops holding the twist) and record
   the largest |current| of each drive over that period (the plant's substeps), signed like the current at the
   period's end.

Over an emulated radio link (``link_up`` / ``link_down``) step 3 is replaced by the robot's and the controller's
sides of the link, in the order `offline.networked` writes down: the same loop with plans (or without, the
uncompensated baseline) and the robot's end of the link (`loop.command_link.CommandLink`), as the lockstep DDS
loop runs them. Through the driver's chain the run is `offline.chain_loop`'s (the loop's chain mode, realtime).

Against the kernels called directly on the exact reference rows the ticks are the same to the last bit
(`test_offline_lockstep`); ``bench --only offline_loop`` measures what the protocol costs over them. The loop
keeps numpy out of its per-tick bookkeeping: it collects the ticks' values and turns them into arrays once, at
the end.

A scenario (`scenarios.SCENARIOS`) names the reference, the controller's
model (`scenarios.Scenario.controller_model`: the robot, or a mismatched one in ``robustness``)
and the odometry noise.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np
from tqdm import tqdm

from robotino_geom_mpc.model.encoders import CONTROLLER_TWIST, DEFAULT_COUNTS_PER_REV, EncoderError, odometry_source
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import DEFAULT_KI, DEFAULT_KP, DEFAULT_RATE_HZ, WheelSpeedLoop, \
    WheelSpeedLoopError

from robotino_geom_mpc.network.link import LinkParams
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.model.driver_chain import ChainParams
from robotino_geom_mpc.offline.chain_loop import run_chain_scenario
from robotino_geom_mpc.offline.lockstep import LockstepController, PreviewRows
from robotino_geom_mpc.offline.networked import NetworkedLoop, link_meta
from robotino_geom_mpc.loop.command_link import CommandLink
from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
from robotino_geom_mpc.loop.events import Now
from robotino_geom_mpc.loop.plan_follower import PlanFollower
from robotino_geom_mpc.loop.robot_loop import PoseNoise, RobotLoop, TwistDrive, VoltageDrive
from robotino_geom_mpc.offline.results import RunData
from robotino_geom_mpc.scenarios import get_scenario

__all__ = ["RunConfig", "SimulationError", "run_scenario", "run_ticks"]


class SimulationError(RobotinoError, ValueError):
    """A bad run setting, named in the message."""


def run_ticks(duration_s: float, period_s: float) -> int:
    """Ticks of a run of `duration_s` at `period_s`: round(duration / Ts), at least 1; SimulationError unless > 0."""
    duration = float(duration_s)
    if not (math.isfinite(duration) and duration > 0.0):
        raise SimulationError(f"duration_s must be positive, got {duration_s!r}")
    return max(1, int(round(duration / period_s)))


@dataclass(frozen=True)
class RunConfig:
    """One offline run's settings (`run_scenario`; the command line, `study`, `tune` and the tests build it).

    Attributes
    ----------
    scenario
        A name of `scenarios.SCENARIOS`.
    robot
        The true robot (the plant), from which the scenario's controller model is made.
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
        (position [m], heading [rad]) noise std; None means the scenario's.
    odometry
        ``ideal`` (the true pose plus the noise, the true twist) or ``encoders``
        (`robotino_geom_mpc.model.encoders`: dead reckoning from the wheel encoders; the
        controller then gets ``control.odometry_twist = period_mean``).
    encoder_counts_per_rev, wheel_slip_std
        The encoders' counts per motor revolution and the wheel slip (std as
        a fraction of the wheel speed; its generator is seeded by `seed`).
    command_interface
        ``voltages`` (the controller's wheel voltages drive the plant) or ``cmd_vel`` (the controller's
        base_link velocity for the next period, `MotionController.next_velocity`, is held by the
        wheel-speed PI loops of `robotino_geom_mpc.model.speed_loop` on the same drives; the voltages
        kept are each period's mean of the PI's).
    wheel_pi
        (kp [V s/rad], ki [V/rad], rate [Hz]) of those loops; None: the plant node's defaults
        (`wheel_speed_loop.DEFAULT_KP`, ...: `tuned_gains` of the Robotino 3 preset, 1 kHz).
    chain
        The real robot's driver and firmware chain (`model.driver_chain`) between controller and plant:
        the run is `chain_loop.run_chain_scenario`'s (cmd_vel only, ideal odometry); None: no chain.
    controller_chain
        What the controller takes the chain to be (e.g. `identify`'s file); `chain` if None.
    link_up, link_down
        The emulated radio link's two directions (`network.link.LinkParams`): odometry and the robot's
        reports up, commands down. With either given (and enabled) the loop is `offline.networked`'s;
        None for both: the scenario's link (``wifi``), else the undelayed loop above, unchanged.
    compensate
        Over a link: the delay-compensating, plan-making controller (`control.delay_compensation`) and
        the robot's plan buffer; False: the plain controller, its command acting on arrival and held
        (the uncompensated baseline).
    """

    scenario: str
    robot: RobotinoParams
    control: ControlParams
    duration_s: float | None = None
    seed: int = 0
    progress: bool = False
    plant_robot: RobotinoParams | None = None
    odometry_noise: tuple[float, float] | None = None
    odometry: str = "ideal"
    encoder_counts_per_rev: int = DEFAULT_COUNTS_PER_REV
    wheel_slip_std: float = 0.0
    command_interface: str = "voltages"
    wheel_pi: tuple[float, float, float] | None = None
    chain: ChainParams | None = None
    controller_chain: ChainParams | None = None
    link_up: LinkParams | None = None
    link_down: LinkParams | None = None
    compensate: bool = True


def run_scenario(config: RunConfig) -> RunData:
    """Simulate one scenario in closed loop: a `loop.robot_loop.RobotLoop` and the controller on one clock.

    Parameters
    ----------
    config
        The run's settings.

    Returns
    -------
    RunData
        One sample per control period; flags ``saturated`` and ``infeasible``,
        the controller's compute times, and meta (seed, mode, noise, mismatch).

    Raises
    ------
    scenarios.ScenarioError
        Unknown scenario.
    SimulationError
        Non-positive duration, negative noise or a bad odometry setting.
    """
    scenario, robot, control, seed = config.scenario, config.robot, config.control, config.seed
    odometry, command_interface, plant_robot = config.odometry, config.command_interface, config.plant_robot
    chain, link_up, link_down = config.chain, config.link_up, config.link_down
    if chain is not None:
        if command_interface != "cmd_vel" or odometry != "ideal":
            raise SimulationError("a chain takes cmd_vel and gives the firmware's odometry: command_interface "
                                  f"must be cmd_vel and odometry ideal, got {command_interface!r}, {odometry!r}")
        return run_chain_scenario(scenario, robot, control, chain, duration_s=config.duration_s, seed=seed,
                                  progress=config.progress, plant_robot=plant_robot,
                                  odometry_noise=config.odometry_noise, controller_chain=config.controller_chain)
    spec = get_scenario(scenario)
    if link_up is None and link_down is None and spec.link is not None:
        link_up = link_down = spec.link
    networked = any(link is not None and link.enabled for link in (link_up, link_down))
    odometry_noise = config.odometry_noise
    if odometry_noise is None:
        odometry_noise = (spec.noise.position_m, spec.noise.yaw_rad)
    noise = tuple(float(v) for v in odometry_noise)
    if len(noise) != 2 or not all(math.isfinite(v) and v >= 0.0 for v in noise):
        raise SimulationError(f"odometry_noise must be two non-negative numbers, got {odometry_noise!r}")
    reference = spec.make_reference()
    Ts, N = control.period_s, control.horizon
    n = run_ticks(reference.duration_s if config.duration_s is None else config.duration_s, Ts)

    plant = RobotinoPlant(plant_robot if plant_robot is not None else robot)
    try:
        source = odometry_source(plant, odometry, config.encoder_counts_per_rev, config.wheel_slip_std, seed)
    except EncoderError as exc:
        raise SimulationError(str(exc)) from None
    if command_interface not in ("voltages", "cmd_vel"):
        raise SimulationError(f"command_interface must be 'voltages' or 'cmd_vel', got {command_interface!r}")
    drive: VoltageDrive | TwistDrive = VoltageDrive(plant)
    if command_interface == "cmd_vel":
        try:
            drive = TwistDrive(plant, WheelSpeedLoop(plant.params, *(config.wheel_pi or (DEFAULT_KP, DEFAULT_KI,
                                                                                         DEFAULT_RATE_HZ))))
        except WheelSpeedLoopError as exc:
            raise SimulationError(str(exc)) from None
    cmd_vel = isinstance(drive, TwistDrive)
    if odometry in CONTROLLER_TWIST:
        control = replace(control, odometry_twist=CONTROLLER_TWIST[odometry])
    loop = ControllerLoop(spec.controller_model(robot), control, Now(0, 0), lockstep=True,
                          interface=command_interface, plans=networked and config.compensate, listeners=QUIET)
    previews = PreviewRows(reference, Ts, round(Ts * 1e9), loop.preview_points, n)
    over_link: NetworkedLoop | None = None
    plain: LockstepController | None = None
    if networked:
        follower = PlanFollower(Ts) if config.compensate else None
        over_link = NetworkedLoop(loop, previews, CommandLink(link_up, link_down, seed, follower))
    else:
        plain = LockstepController(loop, previews)
    # The run's pose noise drawn at once: the same values as one `RobotinoPlant.pose_noise` draw per tick.
    robot_loop = RobotLoop(plant, source, drive, Ts, PoseNoise(noise, seed, n))

    t = np.arange(n) * Ts
    # Only floats and arrays are kept per tick (no tuples): nothing for the garbage collector to scan.
    poses, measured, voltages, saturated, infeasible, compute, substep_currents = [], [], [], [], [], [], []
    measure, drive_period = robot_loop.measure, robot_loop.drive
    for k in tqdm(range(n), desc=scenario, unit="tick", disable=not config.progress, mininterval=0.5):
        pose_measured, twist_measured = measure()
        if plain is not None:
            command = plain.command(k, pose_measured, twist_measured)
            step = plain.step
            flags = (False, False, 0.0) if step is None else (step.saturated, step.infeasible, step.compute_time_s)
        else:
            assert over_link is not None
            start = time.perf_counter()
            command = over_link.command(k, pose_measured, twist_measured)
            flags = (any(abs(v) >= robot.supply_voltage_v for v in command) and not cmd_vel, False,
                     time.perf_counter() - start)
        poses += plant.pose
        measured += pose_measured
        saturated.append(flags[0])
        infeasible.append(flags[1])
        compute.append(flags[2])
        applied, trace = drive_period(command)
        voltages += applied
        substep_currents.append(trace)
    pose = np.array(poses).reshape(n, 3)
    trace = np.array(substep_currents)  # (n, substeps + 1, 3); the last row is the current at the period's end
    currents = np.copysign(np.abs(trace).max(axis=1), trace[:, -1])

    return RunData(
        scenario=scenario,
        t=t,
        pose=pose,
        reference=reference.position(t),
        odometry=np.array(measured).reshape(n, 3),
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
            "odometry": odometry,
            "command_interface": command_interface,
            **({"encoder_counts_per_rev": int(config.encoder_counts_per_rev),
                "wheel_slip_std": float(config.wheel_slip_std)}
               if odometry == "encoders" else {}),
            "controller_mismatch": None if spec.mismatch is None else asdict(spec.mismatch),
            "plant_params": "plant_robot" if plant_robot is not None else "robot",
            **({"link": {"up": link_meta(link_up), "down": link_meta(link_down), **over_link.meta()}}
               if over_link else {}),
        },
    )
