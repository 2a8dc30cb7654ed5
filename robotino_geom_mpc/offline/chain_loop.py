"""Offline closed loop through the real Robotino's chain: the controller's loop -> driver -> link -> firmware -> plant.

The loop of ``simulate --chain NAME`` (`simulation.run_scenario` hands over to `run_chain_scenario`), the run the
nodes make with ``chain.active`` enabled (realtime, cmd_vel), on one simulated clock: the plant behind
`model.chain_emulation.ChainEmulator`, polled by `loop.chain_robot.ChainRobot` as the plant node's
`robotino_sim_node.chain_driver.ChainRun` polls it, and the controller node's protocol, a
`loop.controller_loop.ControllerLoop` in its chain mode (`control.chain_tracking.ChainTracker`). The emulation's
time t is the clock (stamps t in ns). At each driver pass, in this order:

1. the previews due by the pass (`offline.lockstep.PreviewRows`: the trajectory node's realtime preview of every
   control period, stamped k Ts) and the watchdog's checks due (every `LoopSettings.watchdog_period_s`) go to
   the loop at their own times;
2. `ChainRobot.poll` runs the emulation up to the pass: the odometry the driver dispatched, stamped with the pass;
3. each odometry goes to the loop at the pass's time (``on_odometry``), whose twist (`Command`, or zero: `Zero`)
   reaches the driver at once (`ChainRobot.cmd_vel`; the controller's compute time is not simulated) and so
   leaves at the driver's next pass.

The reference the chain controller tracks is the newest preview's (its point nearest each time the controller
asks for, carried by its velocity and acceleration), as over DDS. One sample per firmware tick is recorded (true
pose, reference, the last odometry's pose, the speed loops' mean voltages, the largest currents over the tick), so
the metrics of `results.compute_metrics` apply as they are, with ``control_period_s`` the firmware tick.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
from tqdm import tqdm

from robotino_geom_mpc.loop.chain_robot import ChainRobot
from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
from robotino_geom_mpc.loop.events import Command, Now, PlanarOdometry, Zero
from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import ChainParams
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.offline.lockstep import PreviewRows
from robotino_geom_mpc.offline.results import RunData
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.scenarios import get_scenario

__all__ = ["run_chain_scenario"]

_ZERO = (0.0, 0.0, 0.0)


def run_chain_scenario(scenario: str, robot: RobotinoParams, control: ControlParams, chain: ChainParams, *,
                       duration_s: float | None = None, seed: int = 0, progress: bool = False,
                       plant_robot: RobotinoParams | None = None, odometry_noise: tuple[float, float] | None = None,
                       controller_chain: ChainParams | None = None) -> RunData:
    """Simulate one scenario through the chain.

    Parameters
    ----------
    scenario, robot, control, duration_s, seed, progress, plant_robot, odometry_noise
        As `simulation.run_scenario` (the scenario's model mismatch does not reach this controller, which
        models the chain only; its odometry noise does; `control` gives the previews' period and length).
    chain
        The true chain (the emulation's).
    controller_chain
        What the controller takes the chain to be (e.g. `identify`'s output); `chain` if None.
    """
    spec = get_scenario(scenario)
    if odometry_noise is None:
        odometry_noise = (spec.noise.position_m, spec.noise.yaw_rad)
    reference = spec.make_reference()
    duration = reference.duration_s if duration_s is None else float(duration_s)
    plant = RobotinoPlant(plant_robot if plant_robot is not None else robot)
    x0 = reference.position(np.zeros(1))[0]
    state = np.zeros(9)
    state[[0, 2, 4]] = x0
    plant.reset(state)
    emulated = ChainRobot(ChainEmulator(plant, chain, seed=seed, odometry_noise=tuple(odometry_noise)))
    emulator = emulated.emulator
    emulated.elapsed_s(0.0, 0)  # the emulation's time is the clock: t = 0 at stamp 0
    loop = ControllerLoop(spec.controller_model(robot), control, Now(0, 0), interface="cmd_vel",
                          chain=controller_chain or chain, listeners=QUIET)
    assert loop.chain is not None
    tracker = loop.chain
    n_ticks = max(1, int(round(duration / chain.tick_s)))
    period_ns = round(control.period_s * 1e9)
    previews = PreviewRows(reference, control.period_s, period_ns, loop.preview_points,
                           int((n_ticks * chain.tick_s + chain.driver_period_s) / control.period_s) + 2)
    watchdog_ns = round(loop.settings.watchdog_period_s * 1e9)
    next_preview, next_check = 0, watchdog_ns
    bar = tqdm(total=n_ticks, desc=scenario, unit="tick", disable=not progress, mininterval=0.5)
    odometry = tuple(float(v) for v in x0)
    measured_at_tick: list[tuple[float, ...]] = []
    errors: list[float] = []
    while emulator.next_tick_s() < n_ticks * chain.tick_s - 1e-9:
        t_pass = emulator.next_pass_s()
        pass_ns = round(t_pass * 1e9)
        while next_preview * period_ns <= pass_ns or next_check <= pass_ns:  # step 1, in time order
            if next_preview * period_ns <= next_check:
                stamp = next_preview * period_ns
                loop.on_preview(previews.planar(next_preview), Now(stamp, stamp))
                next_preview += 1
            else:
                _send(emulated, loop.on_watchdog(Now(next_check, next_check)), next_check * 1e-9)
                next_check += watchdog_ns
        before = len(emulator.trace)
        chain_passes = emulated.poll(t_pass, pass_ns)  # step 2: the one pass at t_pass
        measured_at_tick += [odometry] * (len(emulator.trace) - before)
        bar.update(len(emulator.trace) - before)
        for chain_pass in chain_passes:
            for m, measured_s in zip(chain_pass.odometry, chain_pass.measured_s):
                if _send(emulated, loop.on_odometry(PlanarOdometry(m.stamp_ns, m.pose, m.twist),
                                                    Now(m.stamp_ns, m.stamp_ns)), t_pass):
                    clock = tracker.controller.clock
                    assert tracker.epoch_ns is not None
                    errors.append(tracker.epoch_ns * 1e-9 + clock.tick_time(clock.index) - measured_s)
                odometry = m.pose
    bar.close()
    trace = emulator.trace[:n_ticks]
    t = np.array([r.time_s for r in trace])
    timing = np.abs(np.array(errors)) if errors else np.zeros(1)
    return RunData(
        scenario=scenario,
        t=t,
        pose=np.array([r.pose for r in trace]),
        reference=reference.position(t),
        odometry=np.array(measured_at_tick[:n_ticks]),
        currents=np.array([r.currents for r in trace]),
        voltages=np.array([r.voltages for r in trace]),
        control_period_s=chain.tick_s,
        horizon=tracker.controller.horizon,
        nominal_current_a=robot.nominal_current_a,
        supply_voltage_v=robot.supply_voltage_v,
        flags={"saturated": np.array([max(map(abs, r.voltages)) >= robot.supply_voltage_v - 1e-9 for r in trace]),
               "infeasible": np.zeros(len(trace), dtype=bool)},
        compute_time_s=np.zeros(len(trace)),
        meta={
            "seed": int(seed),
            "mode": "chain",
            "odometry_noise": [float(v) for v in odometry_noise],
            "odometry": "ideal",
            "command_interface": "cmd_vel",
            "chain": chain.values(),
            "controller_chain": (controller_chain or chain).values(),
            "round_trip_s": tracker.controller.round_trip_s,
            "measurement_time_error_max_s": float(timing.max()),
            "measurement_time_error_rms_s": float(math.sqrt(np.mean(timing**2))),
            "controller_mismatch": None if spec.mismatch is None else asdict(spec.mismatch),
            "plant_params": "plant_robot" if plant_robot is not None else "robot",
        },
    )


def _send(robot: ChainRobot, outputs: list, now: float) -> bool:
    """The loop's twists (a `Command`, or zero for a `Zero`) to the driver at `now`, as the controller node publishes
    them on ``cmd_vel``; whether an answer (`Command`) was among them.
    """
    answered = False
    for out in outputs:
        if isinstance(out, Command):
            robot.cmd_vel(out.values, now)
            answered = True
        elif isinstance(out, Zero):
            robot.cmd_vel(_ZERO, now)
    return answered
