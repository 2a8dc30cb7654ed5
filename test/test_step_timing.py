"""Time from stamps: a lost, a late and a repeated measurement in the steady paper-circle loop.

The loop is the offline one (`simulation`): the plant holds each voltage until
the next measurement, which is taken after the interval of a schedule; the
controller is told that interval (``dt_s``). Truth: the same loop with every
measurement on time. A timing fault must change no voltage by more than 1 V
and never saturate; telling the controller "one period" instead (the old
behaviour) fails the same bound.
"""

import numpy as np
import pytest

from robotino_geom_mpc.control.motion_controller import MotionController, state_from_odometry
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.model.plant import RobotinoPlant

pytestmark = pytest.mark.unit

FAULT_TICK = 500  # 5 s: well after the start transient
AFTER_S = 3.0  # the old filter error decayed over ~2.8 s
BOUND_V = 1.0


@pytest.fixture(scope="module")
def setup():
    robot, control = load_params()
    reference = make_reference("paper-circle")
    n = FAULT_TICK + int(round(AFTER_S / control.period_s)) + 2
    nominal = _run(robot, control, reference, [control.period_s] * n)
    return robot, control, reference, nominal


def _run(robot, control, reference, intervals, tell_interval=True):
    """Closed loop with the measurement i taken intervals[i-1] after measurement i-1 (the first at t = 0).

    Returns the measurement times, the voltages and the saturation flags.
    """
    Ts, N = control.period_s, control.horizon
    plant, controller = RobotinoPlant(robot), MotionController(robot, control)
    times, voltages, saturated = [0.0], [], []
    for dt in [None, *intervals]:
        if dt is not None:
            plant.step(voltages[-1], dt)
            times.append(times[-1] + dt)
        X = state_from_odometry(*plant.odometry())
        Y_d = reference.position(times[-1] + Ts * np.arange(1, N + 1))
        out = controller.step(X, Y_d, dt if tell_interval else None)
        voltages.append(out.voltages)
        saturated.append(out.saturated)
    return np.array(times), np.array(voltages), np.array(saturated)


def _deviation(setup, intervals, tell_interval=True):
    """Largest |U - U_nominal| over the run, U_nominal the on-time loop's voltage in force at each measurement."""
    robot, control, reference, (_, nominal_U, _) = setup
    times, U, saturated = _run(robot, control, reference, intervals, tell_interval)
    in_force = np.floor(times / control.period_s + 1e-6).astype(int)
    return float(np.abs(U - nominal_U[in_force]).max()), bool(saturated.any())


def _schedule(control, fault):
    """Intervals of a run with one timing fault at FAULT_TICK, back on the grid right after it."""
    Ts = control.period_s
    tail = [Ts] * int(round(AFTER_S / Ts))
    faults = {
        "lost": [2 * Ts],  # one measurement lost: the next comes 20 ms after the last
        "late": [0.021, 2 * Ts - 0.011],  # taken 21 ms after the previous, the next on the grid again
        "repeated": [1e-9, Ts - 1e-9],  # the same tick twice (the node drops duplicates; the core must not care)
    }
    return [Ts] * (FAULT_TICK - 1) + faults[fault] + tail


def test_on_time_loop_tracks_without_saturating(setup):
    robot, control, _, (times, U, saturated) = setup
    assert not saturated.any()
    assert 1.0 < np.abs(U[FAULT_TICK:]).max() < 8.0  # the paper-circle voltages: a few volts


@pytest.mark.parametrize("fault", ["lost", "late", "repeated"])
def test_a_timing_fault_changes_no_voltage_by_more_than_a_volt(setup, fault):
    deviation, saturated = _deviation(setup, _schedule(setup[1], fault))
    assert deviation <= BOUND_V, f"{fault}: {deviation:.3f} V"
    assert not saturated


@pytest.mark.parametrize("fault", ["lost", "late", "repeated"])
def test_assuming_one_period_fails_the_same_bound(setup, fault):
    """The old behaviour (every measurement one period after the last) exceeds the bound: the test can fail."""
    deviation, _ = _deviation(setup, _schedule(setup[1], fault), tell_interval=False)
    assert deviation > BOUND_V, f"{fault}: {deviation:.3f} V"


@pytest.mark.slow
def test_jittered_stamps_stay_within_a_volt(setup):
    """Every measurement up to +-3 ms off its grid time (a loaded host), the intervals told to the controller."""
    control = setup[1]
    n = FAULT_TICK + int(round(AFTER_S / control.period_s))
    times = np.arange(1, n + 1) * control.period_s + np.random.default_rng(0).uniform(-3e-3, 3e-3, n)
    deviation, saturated = _deviation(setup, np.diff(times, prepend=0.0).tolist())
    assert deviation <= BOUND_V and not saturated, f"{deviation:.3f} V"
