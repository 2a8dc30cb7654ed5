"""Offline closed loop through the real Robotino's chain: `ChainController` -> driver -> link -> firmware -> plant.

The loop of ``simulate --chain NAME`` (`simulation.run_scenario` hands over to `run_chain_scenario`): the
plant runs behind `model.chain_emulation.ChainEmulator`; at each pass of the driver's loop that dispatches
odometry, each message goes to `control.chain_controller.ChainController`, whose cmd_vel reaches the driver
at once (the controller's compute time is not simulated) and so leaves at the driver's next pass. One
sample per firmware tick is recorded (true pose, reference, the last odometry's pose, the speed loops'
mean voltages, the largest currents over the tick), so the metrics of `results.compute_metrics` apply as they
are, with ``control_period_s`` the firmware tick.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
from tqdm import tqdm

from robotino_geom_mpc.control.chain_controller import ChainController
from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import ChainParams
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.offline.results import RunData
from robotino_geom_mpc.params.specs import RobotinoParams
from robotino_geom_mpc.scenarios import get_scenario

__all__ = ["run_chain_scenario"]


def run_chain_scenario(scenario: str, robot: RobotinoParams, chain: ChainParams, *, duration_s: float | None = None,
                       seed: int = 0, progress: bool = False, plant_robot: RobotinoParams | None = None,
                       odometry_noise: tuple[float, float] | None = None, controller_chain: ChainParams | None = None,
                       round_trip_s: float | None = None) -> RunData:
    """Simulate one scenario through the chain.

    Parameters
    ----------
    scenario, robot, duration_s, seed, progress, plant_robot, odometry_noise
        As `simulation.run_scenario` (the scenario's model mismatch does not reach this controller, which
        models the chain only; its odometry noise does).
    chain
        The true chain (the emulation's).
    controller_chain, round_trip_s
        What the controller takes the chain to be (e.g. `identify`'s output); `chain` and twice its link
        delay if None.
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
    emulator = ChainEmulator(plant, chain, seed=seed, odometry_noise=tuple(odometry_noise))
    controller = ChainController(controller_chain or chain, round_trip_s)
    odometry = tuple(float(v) for v in x0)
    n_ticks = max(1, int(round(duration / chain.tick_s)))
    bar = tqdm(total=n_ticks, desc=scenario, unit="tick", disable=not progress, mininterval=0.5)
    measured_at_tick: list[tuple[float, ...]] = []
    errors: list[float] = []
    while emulator.next_tick_s() < n_ticks * chain.tick_s - 1e-9:
        before = len(emulator.trace)
        stamp = emulator.next_pass_s()
        messages = emulator.run_until(stamp)
        measured_at_tick += [odometry] * (len(emulator.trace) - before)
        bar.update(len(emulator.trace) - before)
        for message in messages:
            command = controller.step(message.stamp_s, message.pose, message.twist, reference.position)
            errors.append(controller.clock.tick_time(controller.clock.index) - message.measured_s)
            emulator.cmd_vel(command, message.stamp_s)
            odometry = message.pose
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
        horizon=controller.horizon,
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
            "round_trip_s": controller.round_trip_s,
            "measurement_time_error_max_s": float(timing.max()),
            "measurement_time_error_rms_s": float(math.sqrt(np.mean(timing**2))),
            "controller_mismatch": None if spec.mismatch is None else asdict(spec.mismatch),
            "plant_params": "plant_robot" if plant_robot is not None else "robot",
        },
    )
