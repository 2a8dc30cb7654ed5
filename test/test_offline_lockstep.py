"""`simulate` drives the controller's protocol (`ControllerLoop`) in every mode; each run is checked against an
independent driver of the same kernels, tick by tick.

* plain (voltages, cmd_vel, encoder odometry): `MotionController.step` called directly on the exact reference rows
  and the measured state, with the plant behind the same `RobotLoop`. In process the odometry and the preview carry
  the yaw as it is (`PlanarOdometry`, `PlanarPreview`), so the two runs are the same to the last bit, the noisy
  turning robot of robustness included.
* the chain: `ChainController.step` on the emulator's odometry, the cmd_vel given to the emulator at the pass, the
  reference of the newest preview (its point nearest each time, carried by its velocity and acceleration), as the
  controller node's chain mode takes it -- written here from the reference's samples, not through `ChainTracker`.
  The loop's times are integer-ns stamps counted from its first odometry, the test's the emulation's seconds: the
  two agree to 1e-10 m and 1e-8 V over 3 s (the rounding of those times), not to the last bit.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from robotino_geom_mpc.control.chain_controller import ChainController
from robotino_geom_mpc.control.motion_controller import MotionController, state_from_odometry
from robotino_geom_mpc.loop.robot_loop import PoseNoise, RobotLoop, TwistDrive, VoltageDrive
from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import chain_params
from robotino_geom_mpc.model.encoders import CONTROLLER_TWIST, odometry_source
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WheelSpeedLoop
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario, run_ticks
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.specs import ControlParams
from robotino_geom_mpc.scenarios import get_scenario

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params(None)
DURATION_S = 2.0


def _kernels_alone(scenario: str, control: ControlParams, interface: str, odometry: str):
    """The plain run with the kernels called directly: poses, voltages and the step's saturation flags."""
    spec = get_scenario(scenario)
    if odometry in CONTROLLER_TWIST:
        control = replace(control, odometry_twist=CONTROLLER_TWIST[odometry])
    n, Ts, N = run_ticks(DURATION_S, control.period_s), control.period_s, control.horizon
    targets = spec.make_reference().position(np.arange(n + N + 1) * Ts)
    controller = MotionController(spec.controller_model(ROBOT), control)
    controller.start_at(*targets[0].tolist())  # robot and reference start together
    plant = RobotinoPlant(ROBOT)
    drive = VoltageDrive(plant) if interface == "voltages" else TwistDrive(plant, WheelSpeedLoop(ROBOT))
    source = odometry_source(plant, odometry, 2048, 0.0, 0)
    robot = RobotLoop(plant, source, drive, Ts, PoseNoise((spec.noise.position_m, spec.noise.yaw_rad), 0, n))
    poses, voltages, saturated = [], [], []
    for k in range(n):
        poses.append(plant.pose)
        out = controller.step(state_from_odometry(*robot.measure()), targets[k + 1:k + N + 1])
        applied, _ = robot.drive(controller.next_velocity() if interface == "cmd_vel" else out.voltages)
        voltages.append(applied)
        saturated.append(out.saturated)
    return np.array(poses), np.array(voltages), np.array(saturated)


@pytest.mark.parametrize("scenario, interface, odometry, current_limit_a", [
    ("paper-circle", "voltages", "ideal", None), ("robustness", "voltages", "ideal", None),
    ("paper-circle", "cmd_vel", "ideal", None), ("paper-circle", "voltages", "encoders", None),
    ("paper-circle-step", "voltages", "ideal", 0.0)])
def test_simulate_through_the_protocol_is_the_kernels_tick_by_tick(scenario, interface, odometry, current_limit_a):
    control = CONTROL if current_limit_a is None else replace(CONTROL, current_limit_a=current_limit_a)
    poses, voltages, saturated = _kernels_alone(scenario, control, interface, odometry)
    run = run_scenario(RunConfig(scenario, ROBOT, control, duration_s=DURATION_S, command_interface=interface,
                                 odometry=odometry))
    np.testing.assert_array_equal(run.pose, poses)
    np.testing.assert_array_equal(run.voltages, voltages)
    np.testing.assert_array_equal(run.flags["saturated"], saturated)
    assert np.abs(run.voltages).max() > 0.5 and np.abs(run.pose[-1] - run.pose[0]).max() > 0.05  # it moved
    if scenario == "paper-circle-step":
        assert saturated.any()  # the flags are the step's: the paper's start from full speed clips the voltages


def test_simulate_through_the_chain_is_the_chain_controller_on_the_newest_preview():
    """`simulate --chain`: the emulated chain polled pass by pass, each odometry answered through the controller's
    chain mode at the pass, its reference the newest preview's (the trajectory node's every control period).
    """
    chain = chain_params()
    spec = get_scenario("paper-circle")
    duration_s, Ts, N = 3.0, CONTROL.period_s, CONTROL.horizon
    run = run_scenario(RunConfig("paper-circle", ROBOT, CONTROL, duration_s=duration_s, command_interface="cmd_vel",
                                 chain=chain))

    reference = spec.make_reference()
    rows = reference.sample(np.arange(round(duration_s / Ts) + N + 10) * Ts)[:3]  # position, velocity, acceleration
    plant = RobotinoPlant(ROBOT)
    state = np.zeros(9)
    state[[0, 2, 4]] = reference.position(np.zeros(1))[0]
    plant.reset(state)
    emulator = ChainEmulator(plant, chain, seed=0, odometry_noise=(spec.noise.position_m, spec.noise.yaw_rad))
    controller = ChainController(chain)
    n_ticks = round(duration_s / chain.tick_s)
    twists = 0
    while emulator.next_tick_s() < n_ticks * chain.tick_s - 1e-9:
        t_pass = emulator.next_pass_s()
        k = math.floor(t_pass / Ts + 1e-9)  # the newest preview: stamped k Ts, points (k + j) Ts, j = 0..N

        def newest(times, k=k):
            j = np.clip(np.round(np.asarray(times) / Ts - k), 0, N).astype(int) + k
            dt = (np.asarray(times) - j * Ts)[:, None]
            return rows[0][j] + rows[1][j] * dt + 0.5 * rows[2][j] * dt**2

        for message in emulator.run_until(t_pass):
            emulator.cmd_vel(controller.step(message.stamp_s, message.pose, message.twist, newest), t_pass)
            twists += 1
    assert twists > duration_s * 40  # every odometry (50 Hz) answered
    trace = emulator.trace[:n_ticks]
    np.testing.assert_allclose(run.pose, np.array([r.pose for r in trace]), rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(run.voltages, np.array([r.voltages for r in trace]), rtol=0.0, atol=1e-6)
    tracking = np.hypot(*(run.pose[:, :2] - run.reference[:, :2]).T)
    assert np.sqrt(np.mean(tracking[run.t > 1.0] ** 2)) < 2e-3 and np.abs(run.pose[-1] - run.pose[0]).max() > 0.05
