"""Control through the real Robotino's chain (offline): the issue's targets, and the controller's command model."""

import math

import numpy as np
import pytest

from robotino_geom_mpc.control.chain_controller import ChainController, ChainControllerError
from robotino_geom_mpc.model.driver_chain import chain_params
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, SimulationError, run_scenario
from robotino_geom_mpc.params.files import load_params

pytestmark = [pytest.mark.unit, pytest.mark.slow]

WIFI = {"chain.link.delay_s": 0.01, "chain.link.jitter_s": 0.01, "chain.link.loss": 0.05}


@pytest.fixture(scope="module")
def params():
    return load_params()


@pytest.mark.parametrize("scenario, values, rms_max", [
    ("paper-circle", {}, 0.002),
    ("paper-circle", WIFI, 0.005),
    ("robustness", {}, 0.005),
])
def test_tracking_through_the_chain_meets_the_issue_targets(params, scenario, values, rms_max):
    robot, control = params
    run = run_scenario(RunConfig(scenario, robot, control, command_interface="cmd_vel", chain=chain_params(values)))
    m = compute_metrics(run)
    assert m["rms_position_error_m"] <= rms_max
    assert m["peak_current_a"] <= robot.nominal_current_a
    assert run.meta["mode"] == "chain" and run.control_period_s == 0.02


def test_the_planned_velocities_respect_the_ramps_and_the_floor(params):
    chain = chain_params()
    controller = ChainController(chain)
    # a reference far away: the plan wants a large jump, the ramps allow a driver period's worth per command
    reference = lambda t: np.tile([1.0, 0.0, 0.0], (len(t), 1))  # noqa: E731
    stamp, last = 0.007, 0.0
    for k in range(12):
        command = controller.step(stamp, (0.0, 0.0, 0.0), (last, 0.0, 0.0), reference)
        # within what the ramps reach until the next command (the floor aside: the driver would raise it anyway)
        reach = chain.ramp_translation_m_s2 * controller.ramp_time_s
        assert 0.0 < command[0] - last <= reach + 1e-12 or command[0] == chain.speed_floor_translation_m_s
        last = command[0]
        stamp += chain.driver_period_s
    tiny = ChainController(chain)
    command = tiny.step(0.007, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), lambda t: np.tile([2e-4, 0.0, 0.0], (len(t), 1)))
    assert command[0] in (0.0, chain.speed_floor_translation_m_s)  # never a speed the driver would raise


def test_the_prediction_replays_the_firmware_on_the_commands_ticks():
    chain = chain_params()
    controller = ChainController(chain)
    reference = lambda t: np.column_stack([0.2 * t, 0 * t, 0 * t])  # noqa: E731
    command = controller.step(0.007, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), reference)
    tick, sent = controller.commands[-1]
    # forwarded at the next pass (0.007 + 1/30), applied at the firmware tick after (the grid of the first sample)
    assert tick == math.ceil((0.007 + chain.driver_period_s - controller.clock.tick_time(0)) / chain.tick_s - 1e-9)
    assert sent == command
    setpoints = controller._setpoints(0, tick + 3)
    ramp = chain.ramp_translation_m_s2 * chain.tick_s
    expected = [0.0] * tick + [min(command[0], ramp * (j + 1)) for j in range(3)]
    np.testing.assert_allclose([s[0] for s in setpoints], expected, atol=1e-12)


def test_bad_inputs_are_refused(params):
    with pytest.raises(ChainControllerError):
        ChainController(chain_params(), round_trip_s=-1.0)
    controller = ChainController(chain_params())
    with pytest.raises(ChainControllerError, match="finite"):
        controller.step(0.0, (0.0, math.nan, 0.0), (0.0, 0.0, 0.0), lambda t: np.zeros((len(t), 3)))
    robot, control = params
    with pytest.raises(SimulationError, match="cmd_vel"):
        run_scenario(RunConfig("paper-circle", robot, control, chain=chain_params()))
