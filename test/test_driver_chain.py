"""The emulated driver + firmware chain, event by event, against its parameters (model.driver_chain, chain_emulation).

Each expectation is computed here from the parameters alone (the pass grid phase + k / rate, the tick grid
j tick_s, the ramp a tick_s per tick), independently of the emulation's event loop.
"""

import math

import numpy as np
import pytest

from robotino_geom_mpc.model.chain_emulation import ChainEmulator
from robotino_geom_mpc.model.driver_chain import ChainError, ChainParams, chain_params, speed_floor
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def robot():
    return load_params()[0]


def _emulator(robot, **values):
    chain = chain_params({f"chain.{k.replace('__', '.')}": v for k, v in values.items()})
    emulator = ChainEmulator(RobotinoPlant(robot), chain)
    emulator.speed_loop.rate_hz = 200.0  # the timing does not depend on the PI's sampling; faster tests
    return emulator, chain


def _first_pass_after(t, chain, strictly=False):
    """The first driver pass at or (strictly) after t."""
    k = (t - chain.driver_phase_s) / chain.driver_period_s
    k = math.floor(k + 1e-9) + 1 if strictly else math.ceil(k - 1e-9)
    return chain.driver_phase_s + max(k, 0) * chain.driver_period_s


@pytest.mark.parametrize("delay", [0.0, 0.013])
def test_odometry_is_sampled_at_its_rate_and_stamped_at_the_next_pass_after_arrival(robot, delay):
    emulator, chain = _emulator(robot, link__delay_s=delay)
    messages = emulator.run_until(2.0)
    measured = np.array([m.measured_s for m in messages])
    # every sample of the 50 Hz grid, once, in order (dispatch "all", no loss)
    np.testing.assert_allclose(measured, np.arange(len(measured)) * chain.odometry_period_s, atol=1e-12)
    assert measured[-1] >= 2.0 - delay - chain.driver_period_s - chain.odometry_period_s
    for m in messages:
        assert m.stamp_s == pytest.approx(_first_pass_after(m.measured_s + delay, chain), abs=1e-9)
    # what a subscriber sees: stamps on the 30 Hz pass grid, 1 or 2 messages per pass, up to a period late
    passes = np.unique(np.round([m.stamp_s for m in messages], 9))
    periods = np.diff(passes) / chain.driver_period_s
    np.testing.assert_allclose(periods, np.round(periods), atol=1e-7)
    lag = np.array([m.stamp_s - m.measured_s for m in messages]) - delay
    assert lag.min() >= -1e-9 and lag.max() <= chain.driver_period_s + 1e-9 and lag.max() - lag.min() > 0.02


def test_latest_dispatch_sends_only_the_newest_sample_of_a_pass(robot):
    emulator, chain = _emulator(robot, odometry_dispatch="latest")
    messages = emulator.run_until(1.0)
    stamps = [m.stamp_s for m in messages]
    assert len(set(stamps)) == len(stamps)  # one per pass
    for m in messages:  # the newest grid point at or before the pass
        assert m.measured_s == pytest.approx(math.floor(m.stamp_s / chain.tick_s + 1e-9) * chain.tick_s)


def test_each_cmd_vel_is_forwarded_once_at_the_next_pass_and_applied_at_the_next_tick(robot):
    delay = 0.011
    emulator, chain = _emulator(robot, link__delay_s=delay)
    sends = [0.05, 0.1, 0.101, 0.24, chain.driver_phase_s + 9 * chain.driver_period_s]  # the last: at a pass
    for k, t in enumerate(sends):
        emulator.run_until(t)
        emulator.cmd_vel((0.1 + 0.01 * k, 0.0, 0.0), t)
    emulator.run_until(1.0)
    forwarded = emulator.forwarded
    assert [seq for _, seq, _ in forwarded] == list(range(len(sends)))  # each once, in order, never re-sent
    for (time_s, _, twist), t, k in zip(forwarded, sends, range(len(sends))):
        assert time_s == pytest.approx(_first_pass_after(t, chain, strictly=True))
        assert twist == pytest.approx((0.1 + 0.01 * k, 0.0, 0.0))
    applied = dict((seq, tick) for tick, seq in emulator.applied)
    for time_s, seq, _ in forwarded:
        tick = math.ceil((time_s + delay) / chain.tick_s - 1e-9) * chain.tick_s
        later = [s for t2, s, _ in forwarded if s > seq and math.ceil((t2 + delay) / chain.tick_s - 1e-9)
                 * chain.tick_s == tick]
        if later:  # two commands arriving within one tick: the newest wins, the other is never applied
            assert seq not in applied
        else:
            assert applied[seq] == pytest.approx(tick)


def _setpoints(emulator):
    return np.array([r.setpoint for r in emulator.trace])


def _hold(emulator, twist, end_s, every_s=0.1):
    """Send `twist` every `every_s` until `end_s` (within the motor timeout)."""
    for t in np.arange(0.0, end_s, every_s):
        emulator.run_until(t)
        emulator.cmd_vel(twist, t)
    emulator.run_until(end_s)


def test_the_firmware_ramps_and_clips_its_setpoint_each_tick(robot):
    emulator, chain = _emulator(robot)
    _hold(emulator, (0.3, 0.4, 3.0), 2.0)  # translation 0.5 m/s, rotation beyond the 90 deg/s maximum
    sp = _setpoints(emulator)
    first = next(i for i, s in enumerate(sp) if s.any())
    speed = np.hypot(sp[:, 0], sp[:, 1])
    steps = np.diff(speed[first - 1:])
    ramp_ticks = int(round(0.5 / (chain.ramp_translation_m_s2 * chain.tick_s)))
    np.testing.assert_allclose(steps[:ramp_ticks], chain.ramp_translation_m_s2 * chain.tick_s, atol=1e-12)
    np.testing.assert_allclose(sp[first + ramp_ticks:first + ramp_ticks + 5, :2], [[0.3, 0.4]] * 5, atol=1e-12)
    np.testing.assert_allclose(sp[first:, 1] / sp[first:, 0], 4.0 / 3.0)  # direction kept along the ramp
    w = sp[first - 1:, 2]
    rot_ticks = math.ceil(chain.max_rotation_rad_s / (chain.ramp_rotation_rad_s2 * chain.tick_s))
    np.testing.assert_allclose(np.diff(w)[: rot_ticks - 1], chain.ramp_rotation_rad_s2 * chain.tick_s, atol=1e-12)
    assert w.max() == pytest.approx(chain.max_rotation_rad_s)  # clipped to the maximum
    emulator2, _ = _emulator(robot)
    _hold(emulator2, (2.0, 0.0, 0.0), 3.5)
    assert _setpoints(emulator2)[-1][0] == pytest.approx(chain.max_translation_m_s)


def test_the_motors_stop_after_the_timeout(robot):
    emulator, chain = _emulator(robot)
    emulator.cmd_vel((0.1, 0.0, 0.0), 0.0)
    emulator.run_until(1.5)
    arrival = emulator.forwarded[0][0]
    sp = _setpoints(emulator)
    times = np.array([r.time_s for r in emulator.trace])
    stop = math.ceil((arrival + chain.motor_timeout_s) / chain.tick_s - 1e-9)
    assert sp[stop - 1, 0] == pytest.approx(0.1)  # held until the timeout
    assert sp[stop, 0] == pytest.approx(0.1 - chain.ramp_translation_m_s2 * chain.tick_s)  # then ramped to rest
    assert np.all(sp[times > times[stop] + 0.1 / chain.ramp_translation_m_s2 + 1e-9, 0] == 0.0)


@pytest.mark.parametrize("floor", ["enabled", "disabled"])
def test_the_driver_speed_floor(robot, floor):
    chain = chain_params({"chain.speed_floor": floor})
    twist = (0.005, -0.019, 0.03)
    expected = (0.02, -0.02, 0.07) if floor == "enabled" else twist
    assert speed_floor(twist, chain) == pytest.approx(expected)
    assert speed_floor((0.0, 0.5, -0.2), chain) == (0.0, 0.5, -0.2)  # zero and large values pass
    emulator, _ = _emulator(robot, speed_floor=floor)
    emulator.cmd_vel(twist, 0.0)
    emulator.run_until(0.1)
    assert emulator.forwarded[0][2] == pytest.approx(expected)


@pytest.mark.parametrize("name, value, message", [
    ("chain.tick_s", 0.0, "'chain.tick_s'"),
    ("chain.link.loss", 0.9, "'chain.link.loss'"),
    ("chain.ramp_translation_m_s2", float("nan"), "'chain.ramp_translation_m_s2'"),
    ("chain.speed_floor", "maybe", "'chain.speed_floor'"),
    ("chain.odometry_rate_hz", 30.0, "'chain.odometry_rate_hz'"),
    ("chain.driver_phase_s", 0.5, "'chain.driver_phase_s'"),
    ("chain.nonsense", 1.0, "'chain.nonsense'"),
])
def test_out_of_range_chain_parameters_are_refused_by_name(name, value, message):
    with pytest.raises(ChainError, match=message):
        chain_params({name: value})


def test_the_preset_is_the_documented_chain():
    chain = chain_params(preset="robocup-logistics")
    assert chain == ChainParams()
    assert (chain.odometry_rate_hz, chain.driver_rate_hz, chain.tick_s) == (50.0, 30.0, 0.02)
    assert (chain.ramp_translation_m_s2, math.degrees(chain.ramp_rotation_rad_s2)) == pytest.approx((0.4, 180.0))
    assert (chain.max_translation_m_s, math.degrees(chain.max_rotation_rad_s)) == pytest.approx((1.0, 90.0))
    assert (chain.motor_timeout_s, chain.speed_floor_translation_m_s, chain.speed_floor_rotation_rad_s) == \
        (0.5, 0.02, 0.07)
