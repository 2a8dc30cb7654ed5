"""`identify` against the emulated chain: known values recovered, the controller built from its file, refusals."""

import json
from dataclasses import replace

import numpy as np
import pytest

from robotino_geom_mpc.cli import main
from robotino_geom_mpc.model.chain_emulation import ChainEmulator, EmulatedRobot
from robotino_geom_mpc.control.chain_identification import Excitation, IdentifyError, fit_chain, run_excitation
from robotino_geom_mpc.model.driver_chain import chain_params
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.params.files import check_parameter_files, load_params, read_parameter_file

pytestmark = [pytest.mark.unit, pytest.mark.slow]


@pytest.fixture(scope="module")
def robot():
    return load_params()[0]


SETS = [
    {},
    {"chain.link.delay_s": 0.012, "chain.ramp_translation_m_s2": 0.6, "chain.ramp_rotation_rad_s2": 2.5,
     "chain.speed_loop_time_constant_s": 0.04},
    {"chain.link.delay_s": 0.03, "chain.ramp_translation_m_s2": 0.3, "chain.ramp_rotation_rad_s2": 4.0,
     "chain.speed_loop_time_constant_s": 0.06, "chain.driver_phase_s": 0.02},
]


@pytest.mark.parametrize("values", SETS)
def test_identify_recovers_known_chains(robot, values):
    truth = chain_params(values)
    recording = run_excitation(EmulatedRobot(ChainEmulator(RobotinoPlant(robot), truth, seed=1)))
    fit = fit_chain(recording, chain_params())  # the preset as the prior, whatever the truth
    assert abs(fit.round_trip_s - 2.0 * truth.link_delay_s) <= 0.005
    assert fit.ramp_translation_m_s2 == pytest.approx(truth.ramp_translation_m_s2, rel=0.1)
    assert fit.ramp_rotation_rad_s2 == pytest.approx(truth.ramp_rotation_rad_s2, rel=0.1)
    assert fit.speed_loop_time_constant_s == pytest.approx(truth.speed_loop_time_constant_s, rel=0.1)


def test_the_excitation_stays_within_its_bounds(robot):
    excitation = Excitation()
    emulator = ChainEmulator(RobotinoPlant(robot), chain_params(), seed=1)
    recording = run_excitation(EmulatedRobot(emulator), excitation)
    assert recording.stamps[-1] - recording.stamps[0] < excitation.duration_s + 0.1
    c = recording.commands
    assert np.abs(c[:, :2]).max() <= excitation.speed_m_s + excitation.probe_m_s + 1e-12
    assert np.abs(c[:, 2]).max() <= excitation.rate_rad_s + excitation.probe_rad_s + 1e-12
    rates = np.abs(np.diff(c, axis=0)) / np.diff(recording.command_times)[:, None]
    assert rates[:, :2].max() <= excitation.acceleration_m_s2 + 1e-9
    assert rates[:, 2].max() <= excitation.acceleration_rad_s2 + 1e-9
    assert emulator.forwarded[-1][2] == (0.0, 0.0, 0.0)  # left at rest


class _Mirrored:
    """Odometry whose twist comes out in the wrong axes (x and y swapped): a robot that moves, but not as told."""

    def __init__(self, plant):
        self.plant = plant

    def noisy_odometry(self, draw):
        pose, (vx, vy, w) = self.plant.noisy_odometry(draw)
        return pose, (vy, vx, w)


@pytest.mark.parametrize("case, reason", [
    ("no motion", "no motion"),
    ("saturation", "saturation"),
    ("mirrored", "does not move as commanded"),
])
def test_an_excitation_that_cannot_identify_stops_the_robot_and_says_why(robot, case, reason):
    plant_robot = {"no motion": replace(robot, supply_voltage_v=1e-3),
                   "saturation": replace(robot, supply_voltage_v=3.0)}.get(case, robot)
    plant = RobotinoPlant(plant_robot)
    emulator = ChainEmulator(plant, chain_params(), seed=1, source=_Mirrored(plant) if case == "mirrored" else None)
    io = EmulatedRobot(emulator)
    with pytest.raises(IdentifyError, match=reason) as info:
        run_excitation(io)
    assert "stopped" in str(info.value)
    stopped_at = io.now_s
    assert io.emulator.next_pass_s() - stopped_at < 0.05  # it stopped at once, not after the whole excitation
    emulator.run_until(stopped_at + 2.0)
    assert emulator.forwarded[-1][2] == (0.0, 0.0, 0.0)
    assert np.abs(emulator.trace[-1].setpoint).max() == 0.0  # the firmware ramped the robot to rest
    assert stopped_at < Excitation().duration_s


def test_identify_cli_writes_a_file_the_controller_takes_and_the_controller_meets_the_target(robot, tmp_path, capsys):
    out = tmp_path / "id"
    assert main(["identify", "--chain", "robocup-logistics", "--out", str(out)]) == 0
    path = out / "chain_params.yaml"
    check_parameter_files([path])  # as a node would check it
    values = read_parameter_file(path, "robotino_controller")
    assert values["chain.active"] == "enabled"
    controller_chain = chain_params({k: v for k, v in values.items() if k.startswith("chain.") and k != "chain.active"})
    report = json.loads((out / "identify.json").read_text())
    assert report["truth"] == chain_params().values()
    control = load_params()[1]
    run = run_scenario(RunConfig("paper-circle", robot, control, command_interface="cmd_vel", chain=chain_params(),
                                 controller_chain=controller_chain))
    m = compute_metrics(run)
    assert m["rms_position_error_m"] <= 0.002 and m["peak_current_a"] <= robot.nominal_current_a


def test_identify_cli_refuses_bad_chain_parameters_by_name(tmp_path, capsys):
    assert main(["identify", "--chain-set", "chain.link.loss=0.9", "--out", str(tmp_path)]) == 2
    assert "chain.link.loss" in capsys.readouterr().err
