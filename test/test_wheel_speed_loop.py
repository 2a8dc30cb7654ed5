"""The plant's wheel-speed PI loop (cmd_vel path) against the plant's own integration, and the offline cmd_vel loop."""

import math

import numpy as np
import pytest

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, SimulationError, run_scenario
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import DEFAULT_KI, DEFAULT_KP, SPEED_LOOP_TIME_CONSTANT_S, WheelSpeedLoop, \
    WheelSpeedLoopError, tuned_gains

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def robot():
    return load_params()[0]


def _body_twist(plant: RobotinoPlant) -> np.ndarray:
    return np.array(plant.odometry()[1])


def test_the_loop_holds_the_commanded_body_twist(robot):
    plant = RobotinoPlant(robot)
    plant.reset(np.array([0.0, 0.0, 0.0, 0.0, 0.7, 0.0, 0.0, 0.0, 0.0]))  # heading 0.7 rad: base_link is not odom
    loop = WheelSpeedLoop(robot)
    twist = (0.25, -0.1, 0.8)
    for _ in range(300):  # 3 s: the integrators take out the rest (turning has its own pole, not cancelled)
        loop.run(plant, twist, 0.01)
    np.testing.assert_allclose(_body_twist(plant), twist, rtol=1e-3, atol=1e-6)


def test_a_speed_step_settles_with_the_tuned_time_constant(robot):
    plant = RobotinoPlant(robot)
    loop = WheelSpeedLoop(robot)
    target = 0.05  # small enough for the PI's voltages to stay below the supply
    loop.run(plant, (target, 0.0, 0.0), SPEED_LOOP_TIME_CONSTANT_S)
    reached = _body_twist(plant)[0] / target  # first order: 63 % after one time constant
    assert reached == pytest.approx(1.0 - math.exp(-1.0), abs=0.03)
    loop.run(plant, (target, 0.0, 0.0), 0.2)
    assert _body_twist(plant)[0] == pytest.approx(target, rel=5e-3)


def test_clipped_voltages_do_not_wind_the_integrator_up(robot):
    plant = RobotinoPlant(robot)
    loop = WheelSpeedLoop(robot)
    voltages, _ = loop.run(plant, (5.0, 0.0, 0.0), 0.5)  # far beyond the motors: clipped all along
    assert np.abs(voltages).max() == pytest.approx(robot.supply_voltage_v)
    assert max(abs(loop.ki * i) for i in loop.integral) < 2.0 * robot.supply_voltage_v
    loop.run(plant, (0.3, 0.0, 0.0), 1.0)  # back to a feasible speed: no long windup overshoot
    assert _body_twist(plant)[0] == pytest.approx(0.3, rel=5e-3)


def test_the_default_gains_are_the_tuned_ones_of_the_preset(robot):
    np.testing.assert_allclose((DEFAULT_KP, DEFAULT_KI), tuned_gains(robot), rtol=5e-3)


@pytest.mark.parametrize("kwargs", [{"kp": 0.0}, {"ki": -1.0}, {"rate_hz": math.nan}, {"kp": "1"}])
def test_bad_gains_are_refused(robot, kwargs):
    with pytest.raises(WheelSpeedLoopError):
        WheelSpeedLoop(robot, **kwargs)


def test_a_non_finite_twist_is_refused(robot):
    with pytest.raises(WheelSpeedLoopError):
        WheelSpeedLoop(robot).run(RobotinoPlant(robot), (math.nan, 0.0, 0.0), 0.01)


def test_the_offline_cmd_vel_loop_tracks_the_circle():
    robot, control = load_params()
    data = run_scenario(RunConfig("paper-circle", robot, control, duration_s=4.0, command_interface="cmd_vel"))
    metrics = compute_metrics(data)
    assert data.meta["command_interface"] == "cmd_vel"
    assert metrics["max_position_error_m"] < 1e-3  # closed loop: sub-millimetre on the circle
    assert metrics["peak_current_a"] < robot.nominal_current_a
    with pytest.raises(SimulationError, match="command_interface"):
        run_scenario(RunConfig("paper-circle", robot, control, duration_s=0.1, command_interface="torque"))
