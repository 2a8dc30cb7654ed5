"""The lockstep loop of the two plain objects -- the controller's protocol (`ControllerLoop`, fed as the nodes feed it
in lockstep) and the robot (`RobotLoop`) -- against `simulation.run_scenario`'s kernel loop, tick by tick: the same
poses and voltages (an independent driver of the same kernels: MotionController.step and the plant). Through the
protocol the odometry's and the preview's yaw travel as quaternions, as over DDS: with a turning robot and noise
(robustness) the two differ by rounding (1e-15 m, 1e-12 V); without (paper-circle's constant heading) not at all.
"""

import numpy as np
import pytest

from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
from robotino_geom_mpc.loop.events import Now
from robotino_geom_mpc.loop.robot_loop import PoseNoise, RobotLoop, TwistDrive, VoltageDrive
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WheelSpeedLoop
from robotino_geom_mpc.offline.lockstep import LockstepController, PreviewRows
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario, run_ticks
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.scenarios import get_scenario

pytestmark = pytest.mark.unit

ROBOT, CONTROL = load_params(None)
DURATION_S = 2.0


@pytest.mark.parametrize("scenario, interface", [("paper-circle", "voltages"), ("robustness", "voltages"),
                                                 ("paper-circle", "cmd_vel")])
def test_the_lockstep_loop_of_the_two_objects_is_simulate(scenario, interface):
    spec = get_scenario(scenario)
    n, Ts = run_ticks(DURATION_S, CONTROL.period_s), CONTROL.period_s
    loop = ControllerLoop(spec.controller_model(ROBOT), CONTROL, Now(0, 0), lockstep=True, interface=interface,
                          listeners=QUIET)
    controller = LockstepController(loop, PreviewRows(spec.make_reference(), Ts, round(Ts * 1e9),
                                                      loop.preview_points, n))
    plant = RobotinoPlant(ROBOT)
    drive = VoltageDrive(plant) if interface == "voltages" else TwistDrive(plant, WheelSpeedLoop(ROBOT))
    robot = RobotLoop(plant, plant, drive, Ts, PoseNoise((spec.noise.position_m, spec.noise.yaw_rad), 0))
    poses, voltages = [], []
    for k in range(n):
        poses.append(plant.pose)
        applied, _ = robot.drive(controller.command(k, *robot.measure()))
        voltages.append(applied)
    run = run_scenario(RunConfig(scenario, ROBOT, CONTROL, duration_s=DURATION_S, command_interface=interface))
    np.testing.assert_allclose(np.array(poses), run.pose, rtol=0.0, atol=1e-13)
    np.testing.assert_allclose(np.array(voltages), run.voltages, rtol=0.0, atol=1e-10)
    if scenario == "paper-circle":
        np.testing.assert_array_equal(np.array(poses), run.pose)
    assert np.abs(run.voltages).max() > 0.5 and np.abs(run.pose[-1] - run.pose[0]).max() > 0.05  # it moved
