"""Measurement times reconstructed from unstamped 50 Hz odometry stamped on dispatch, against the emulation's truth."""

import math

import numpy as np
import pytest

from robotino_geom_mpc.control.measurement_times import MeasurementClock, MeasurementClockError
from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import chain_params
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.offline.chain_loop import run_chain_scenario
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def robot():
    return load_params()[0]


def _messages(robot, values, seconds=6.0, seed=3):
    chain = chain_params(values)
    emulator = ChainEmulator(RobotinoPlant(robot), chain, seed=seed)
    emulator.speed_loop.rate_hz = 100.0
    return chain, emulator.run_until(seconds)


@pytest.mark.parametrize("values", [
    {},
    {"chain.link.delay_s": 0.01},
    {"chain.link.delay_s": 0.01, "chain.link.jitter_s": 0.01},
    {"chain.driver_phase_s": 0.031, "chain.link.delay_s": 0.004},
    {"chain.odometry_dispatch": "latest", "chain.link.delay_s": 0.01},
])
def test_reconstructed_times_are_within_their_stated_uncertainty_of_the_truth(robot, values):
    chain, messages = _messages(robot, values)
    clock = MeasurementClock(chain.odometry_period_s, chain.driver_period_s, chain.link_delay_s, chain.link_jitter_s,
                             chain.odometry_dispatch == "latest")
    times = [clock.update(m.stamp_s) for m in messages]
    error = np.array([r.time_s - m.measured_s for r, m in zip(times, messages)])
    bound = np.array([r.uncertainty_s for r in times])
    settled = np.array([m.stamp_s > 1.0 for m in messages])
    assert np.all(np.abs(error[settled]) <= bound[settled] + 1e-9)
    # after a second the pattern of 30 Hz passes over the 50 Hz grid has pinned the offset to T / 5 = 6.7 ms
    # (+-3.3 ms); a jitter J loosens the lower bounds (1) by J
    assert bound[settled].max() <= 0.5 * (chain.driver_period_s / 5.0 + chain.link_jitter_s) + 1e-9
    stamp_error = np.array([m.stamp_s - m.measured_s for m in messages])
    assert np.abs(error[settled]).max() < 0.25 * np.ptp(stamp_error)  # the stamps themselves spread by ~33 ms
    assert clock.restarts == 0


def test_a_lost_sample_is_placed_by_the_pose_chooser():
    clock = MeasurementClock(0.02, 1 / 30, 0.0, 0.0)
    truth = np.arange(60) * 0.02
    stamps = 0.007 + np.ceil((truth - 0.007) * 30 - 1e-9) / 30
    keep = np.ones(len(truth), bool)
    keep[40] = False  # lost on the link
    got = []
    for t, s in zip(truth[keep], stamps[keep]):
        got.append(clock.update(s, lambda cands, t=t: int(np.argmin([abs(c - t) for c in cands]))).time_s)
    settled = truth[keep] > 0.5  # the first messages only bound the grid's offset to a pass period
    np.testing.assert_allclose(np.array(got)[settled], truth[keep][settled], atol=clock.P / 5)


def test_stamps_going_back_are_refused():
    clock = MeasurementClock(0.02, 1 / 30)
    clock.update(1.0)
    with pytest.raises(MeasurementClockError):
        clock.update(0.5)
    with pytest.raises(MeasurementClockError):
        clock.update(math.nan)


def test_in_the_closed_loop_over_a_lossy_link_the_times_stay_reconstructed(robot):
    chain = chain_params({"chain.link.delay_s": 0.01, "chain.link.jitter_s": 0.01, "chain.link.loss": 0.05})
    run = run_chain_scenario("paper-circle", robot, load_params()[1], chain, duration_s=6.0)
    # the controller's pose chooser places the samples after a loss; without it a lost sample shifts all later
    # times by a period (20 ms)
    assert run.meta["measurement_time_error_rms_s"] < 0.005
