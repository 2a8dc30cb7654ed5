"""Closed-loop poles of the Delta-u MPC (eqs. 49, 56) against the closed loop simulated step by step."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.control.mpc import (
    DecoupledMPC,
    MPCError,
    UnstableClosedLoopError,
    axis_dampings,
    check_closed_loop,
    closed_loop_poles,
    discretize_axis,
)
from robotino_geom_mpc.params.specs import ParamError
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit

STEPS = 1500
GROWN = 1e9  # a norm this many times the start's is growth


@pytest.fixture(scope="module")
def params():
    return load_params()


def _simulated_growth(robot, control, seed=0):
    """Per axis: the norm of (pos, vel, u(k-1)) after STEPS steps over its start, at most GROWN.

    The law is the controller's own (`DecoupledMPC.delta_u`, eq. 56's first increment;
    reference zero); the plant is each axis discretised on its own (`discretize_axis`, tested
    against ODE integration). Python floats: a few microseconds per step.
    """
    mpc = DecoupledMPC(robot, control)
    models = [[m.tolist() for m in discretize_axis(d, control.period_s)] for d in axis_dampings(robot)]
    rng = np.random.default_rng(seed)
    z0 = rng.normal(0.0, 1e-3, (3, 3))  # per axis: pos, vel, u(k-1)
    X, u = z0[:, :2].ravel().tolist(), z0[:, 2].tolist()
    Y_d = [[0.0, 0.0, 0.0]] * control.horizon
    grown, frozen = GROWN * np.abs(z0).max(), [False] * 3
    for _ in range(STEPS):
        u_next = [ua + da for ua, da in zip(u, mpc.delta_u(X, u, Y_d))]
        X_next = [
            value
            for ((a00, a01), (a10, a11)), (b0, b1), p, v, ua in zip(*zip(*models), X[0::2], X[1::2], u_next)
            for value in (a00 * p + a01 * v + b0 * ua, a10 * p + a11 * v + b1 * ua)
        ]
        # an axis that has grown stays where it is (no overflow); the others run on: the axes are decoupled, and
        # stopping all at the first to grow cut a stable axis off in its transient (radius 0.973 judged grown)
        for i in range(3):
            if not frozen[i]:
                X[2 * i:2 * i + 2], u[i] = X_next[2 * i:2 * i + 2], u_next[i]
                frozen[i] = max(abs(X[2 * i]), abs(X[2 * i + 1]), abs(u[i])) > grown
        if all(frozen):
            break
    z = np.column_stack((np.reshape(X, (3, 2)), u))
    return np.minimum(np.linalg.norm(z, axis=1) / np.linalg.norm(z0, axis=1), GROWN)


def test_default_weights_are_stable_and_the_loop_decays(params):
    robot, control = params
    radii = check_closed_loop(robot, control)
    np.testing.assert_allclose(radii, np.abs(closed_loop_poles(robot, control)).max(axis=1))
    assert np.all(radii < 0.9)
    assert np.all(_simulated_growth(robot, control) < 1e-6)


def test_q_x_of_two_is_refused_naming_the_axis_and_the_loop_grows(params):
    """The live set of the fail-safe issue: q_x = 2.0 (q/r = 6.7) oscillated the robot at saturation."""
    robot, control = params
    unstable = replace(control, q_x=2.0)
    radii = np.abs(closed_loop_poles(robot, unstable)).max(axis=1)
    assert radii[0] > 1.0 and np.all(radii[1:] < 1.0)
    growth = _simulated_growth(robot, unstable)
    assert growth[0] > 1e2 and np.all(growth[1:] < 1e-6)  # x: about radius ** 1500 = 5e2
    message = rf"axis x: spectral radius {radii[0]:.6f} \(q_x = 2, r_x = 0.3"
    with pytest.raises(UnstableClosedLoopError, match=message) as err:
        check_closed_loop(robot, unstable)
    assert "axis y" not in str(err.value) and "axis theta" not in str(err.value)
    assert isinstance(err.value, RobotinoError) and isinstance(err.value, ParamError)


@settings(max_examples=25, deadline=None)
@given(
    log_q=st.floats(-1.0, 8.0),
    log_r=st.floats(-3.0, 2.0),
    horizon=st.integers(1, 12),
    period_s=st.sampled_from([0.005, 0.01, 0.02]),
)
@example(log_q=7.15625, log_r=-0.5, horizon=3, period_s=0.005)  # x stable (0.973) beside fast-growing y, theta
def test_poles_predict_growth_of_the_simulated_loop(params, log_q, log_r, horizon, period_s):
    """The loop grows iff the spectral radius is >= 1 (radius at least 2 % off 1, so 1500 steps decide)."""
    robot, control = params
    control = replace(control, q_x=10.0**log_q, r_x=10.0**log_r, horizon=horizon, period_s=period_s)
    radius = np.abs(closed_loop_poles(robot, control)).max(axis=1)[0]
    assume(abs(radius - 1.0) > 0.02)
    grows = _simulated_growth(robot, control)[0] > 1.0
    assert grows == (radius >= 1.0), f"radius {radius:.4f}"
    try:
        check_closed_loop(robot, control)
        refused = False
    except UnstableClosedLoopError as err:
        refused = "axis x" in str(err)
    assert refused == (radius >= 1.0 - 1e-3)


def test_margin_refuses_poles_just_inside_the_unit_circle(params):
    robot, control = params
    radius = float(np.abs(closed_loop_poles(robot, control)).max())
    check_closed_loop(robot, control, margin=0.0)
    with pytest.raises(UnstableClosedLoopError, match="limit 1 - "):
        check_closed_loop(robot, control, margin=1.0 - radius + 1e-9)
    for margin in (-0.1, 1.0, float("nan")):
        with pytest.raises(MPCError, match="margin"):
            check_closed_loop(robot, control, margin=margin)
    with pytest.raises(MPCError, match="weights"):
        closed_loop_poles(robot, replace(control, r_theta=0.0))
