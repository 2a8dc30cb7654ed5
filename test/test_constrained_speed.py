"""Constrained mode's speed path: the screen, the QP only where a limit binds, DAQP's warm start, the benchmark.

No wall time is asserted: the work is counted (QP solves, active-set iterations)
and the benchmark's two sides must agree.
"""

import functools
from dataclasses import replace

import daqp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from robotino_geom_mpc.bench.constrained import (
    OsqpConstrainedQP,
    constrained_inputs,
    fastest_agreeing,
    qp_arguments,
    qp_calls,
)
from robotino_geom_mpc.bench.controller_step import OSQP_TOLERANCES
from robotino_geom_mpc.control.constrained import ConstrainedMPC
from robotino_geom_mpc.control.mpc import DecoupledMPC
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def inputs():
    return constrained_inputs(300, 60)


_MODEL = daqp.Model


class _CountingModel:
    """daqp.Model keeping the iteration count of each solve."""

    iterations: list[int] = []

    def __init__(self):
        self._model = _MODEL()

    def __getattr__(self, name):
        return getattr(self._model, name)

    def __setattr__(self, name, value):
        if name == "_model":
            object.__setattr__(self, name, value)
        else:
            setattr(self._model, name, value)

    def solve(self):
        result = self._model.solve()
        _CountingModel.iterations.append(int(result[3]["iterations"]))
        return result


def _solver():
    robot, control = load_params()
    control = replace(control, mode="constrained")
    return ConstrainedMPC(robot, control, DecoupledMPC(robot, control))


def test_qp_runs_only_where_a_limit_binds(inputs, monkeypatch):
    _, control = load_params()
    solved = []
    original = ConstrainedMPC._solve_qp
    monkeypatch.setattr(ConstrainedMPC, "_solve_qp", lambda self, *a: solved.append(1) or original(self, *a))
    for name in ("paper-circle", "circle-step"):
        solved.clear()
        calls = qp_calls(inputs[name], control)
        assert len(solved) == sum(not call.closed_form for call in calls)
        if name == "paper-circle":
            assert not solved
        else:
            assert len(solved) >= 5


def test_warm_start_from_the_last_active_set_saves_iterations_and_keeps_the_answer(inputs, monkeypatch):
    _, control = load_params()
    calls = [c for c in qp_calls(inputs["circle-step"], control) if not c.closed_form]
    monkeypatch.setattr(daqp, "Model", _CountingModel)
    qp = _solver()
    _CountingModel.iterations = []
    warm = [qp.solve(c.X, c.u_prev, c.Y_d, c.i_start)[0] for c in calls]
    warm_iterations = list(_CountingModel.iterations)
    _CountingModel.iterations = []
    cold = []
    for c in calls:
        qp.reset()
        cold.append(qp.solve(c.X, c.u_prev, c.Y_d, c.i_start)[0])
    cold_iterations = list(_CountingModel.iterations)
    assert len(warm_iterations) == len(cold_iterations) == len(calls)
    np.testing.assert_allclose(np.array(warm), np.array(cold), rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.array(warm), np.array([c.u for c in calls]), rtol=0, atol=1e-9)
    assert sum(warm_iterations) < sum(cold_iterations)


def test_osqp_peer_is_the_loosest_polished_tolerance_that_agrees():
    """The benchmark's OSQP peer: polished, the loosest tolerance giving u to 1e-6; a looser one does not.

    The truth is the tight OSQP (1e-12, no polishing) on the same QPs; the
    circle at full speed from rest is where OSQP's polishing at 1e-3 misses (after its 60th tick).
    """
    _, control = load_params()
    name = "circle-step"
    transient = constrained_inputs(1, 100)[name]
    calls = {name: qp_calls(transient, control)}
    model = transient.model
    qp = ConstrainedMPC(model, replace(control, mode="constrained"), DecoupledMPC(model, control))
    problems = {name: [qp_arguments(qp, call) for call in calls[name]]}
    tight = OsqpConstrainedQP(qp)
    truth = np.array([call.u_prev + tight.solve(*problem)[:3] for call, problem in zip(calls[name], problems[name])])
    scale = max(1.0, float(np.abs(truth).max()))

    def difference(eps: float) -> float:
        peer = OsqpConstrainedQP(qp, eps=eps, polishing=True)
        u = np.array([call.u_prev + peer.solve(*problem)[:3] for call, problem in zip(calls[name], problems[name])])
        return float(np.abs(u - truth).max()) / scale

    eps, _ = fastest_agreeing({name: qp}, calls, problems)
    looser = [tol for tol in OSQP_TOLERANCES if tol > eps]
    assert difference(eps) <= 1.1e-6
    assert looser and difference(min(looser)) > 1e-6  # the next looser one misses


class _CountingChecks(ConstrainedMPC):
    """ConstrainedMPC counting its full checks (`_check`): a `solve_floats` without one was passed by the screen."""

    checks = 0

    def _check(self, w):
        self.checks += 1
        return super()._check(w)

    def screened(self, X, u_prev, Y_d, i_start):
        """u of `solve_floats` on the arrays' floats, and whether the screen passed it."""
        before = self.checks
        u, _ = self.solve_floats(X.tolist(), u_prev.tolist(), Y_d.tolist(), i_start.tolist())
        return u, self.checks == before


def _pair(model, control):
    """A counting solver and a plain one (its `solve` always runs the full check) on the same model."""
    mpc = DecoupledMPC(model, control)
    return _CountingChecks(model, control, mpc), ConstrainedMPC(model, control, mpc)


@functools.lru_cache(maxsize=1)
def _constrained() -> tuple:
    """The preset's robot and its control parameters in constrained mode (read once: the property's examples)."""
    robot, control = load_params()
    return robot, replace(control, mode="constrained")


def test_screen_passes_only_feasible_ticks_and_keeps_u_bit_for_bit(inputs):
    """On every bench input: each screened tick's rows (the full check, independent instance) lie in [-1, 1],
    u equals the always-checking `solve` bit for bit, and the screen decides most nominal ticks.
    """
    _, control = load_params()
    control = replace(control, mode="constrained")
    for name, inputs_set in inputs.items():
        calls = qp_calls(inputs_set, control)
        screen, full = _pair(inputs_set.model, control)
        passed = 0
        for c in calls:
            u, by_screen = screen.screened(c.X, c.u_prev, c.Y_d, c.i_start)
            assert u == full.solve(c.X, c.u_prev, c.Y_d, c.i_start)[0].tolist()  # bit for bit
            if by_screen:
                passed += 1
                assert np.abs(full.closed_form_rows(c.X, c.u_prev, c.Y_d, c.i_start)).max() <= 1.0
        if name in ("paper-circle", "robustness"):
            assert passed >= 0.75 * len(calls), (name, passed)
        else:  # the limits bind on (nearly) every tick of the transients
            assert passed <= 0.1 * len(calls), (name, passed)


def _tick(rng, scale_y):
    """A random tick (X, u(k-1), Y_d, i_0) near the closed form's limits when scale_y is large."""
    control = _constrained()[1]
    X = rng.normal(0.0, [0.5, 0.3, 0.5, 0.3, 3.0, 0.5])
    Ts, N = control.period_s, control.horizon
    Y_d = X[0::2] + np.outer(np.arange(1, N + 1) * Ts, X[1::2]) + rng.normal(0.0, scale_y, (N, 3))
    return X, rng.normal(0.0, 0.3, 3), Y_d, rng.normal(0.0, 0.2, 3)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), size=st.floats(-7.0, -0.5), scale_y=st.floats(-5.0, -2.5),
       shift=st.floats(-50.0, 50.0))
def test_screen_never_passes_a_tick_the_full_check_fails(seed, size, scale_y, shift):
    """Property: from a checked reference tick, any other tick (moved by 10**size in every input, and its
    positions translated by `shift` metres) that the screen passes meets every limit, with the closed form's u.
    """
    rng = np.random.default_rng(seed)
    X, u_prev, Y_d, i_start = _tick(rng, 10.0**scale_y)
    screen, full = _pair(*_constrained())
    assume(np.abs(full.closed_form_rows(X, u_prev, Y_d, i_start)).max() <= 1.0)
    screen.screened(X, u_prev, Y_d, i_start)  # the full check: the reference
    step = 10.0**size
    X2 = X + step * rng.normal(0.0, 1.0, 6)
    X2[[0, 2]] += shift
    Y_d2 = Y_d + step * rng.normal(0.0, 1.0, Y_d.shape)
    Y_d2[:, :2] += X2[[0, 2]] - X[[0, 2]] - step * rng.normal(0.0, 1.0, 2)  # the preview follows the robot
    u_prev2, i_start2 = u_prev + step * rng.normal(0.0, 1.0, 3), i_start + step * rng.normal(0.0, 1.0, 3)
    u, by_screen = screen.screened(X2, u_prev2, Y_d2, i_start2)
    if by_screen:
        assert np.abs(full.closed_form_rows(X2, u_prev2, Y_d2, i_start2)).max() <= 1.0
        assert u == full.solve(X2, u_prev2, Y_d2, i_start2)[0].tolist()


def test_screen_decides_small_changes_and_defers_large_ones():
    """The property above is not vacuous: a 1e-7 change of a feasible tick is screened, a change that
    drives the closed form over a limit is not (the full check runs and the QP answers).
    """
    robot, control = load_params()
    control = replace(control, mode="constrained")
    X, u_prev, Y_d, i_start = _tick(np.random.default_rng(5), 1e-4)
    screen, full = _pair(robot, control)
    assert np.abs(full.closed_form_rows(X, u_prev, Y_d, i_start)).max() <= 0.5
    assert not screen.screened(X, u_prev, Y_d, i_start)[1]  # no reference yet
    assert screen.screened(X + 1e-7, u_prev, Y_d + 1e-7, i_start)[1]
    far = Y_d + np.array([0.05, -0.03, 0.2])  # amperes wanted: a limit binds
    assert np.abs(full.closed_form_rows(X, u_prev, far, i_start)).max() > 1.0
    u, by_screen = screen.screened(X, u_prev, far, i_start)
    assert not by_screen and u == full.solve(X, u_prev, far, i_start)[0].tolist()


def test_a_binding_tick_drops_the_screen_reference():
    """After a tick where a limit binds, the next tick is checked in full even when the old reference would
    screen it, and its u is the closed form's; then the screen passes ticks near it again.
    """
    robot, control = load_params()
    control = replace(control, mode="constrained")
    X, u_prev, Y_d, i_start = _tick(np.random.default_rng(5), 1e-4)
    screen, full = _pair(robot, control)
    screen.screened(X, u_prev, Y_d, i_start)  # the reference
    assert screen.screened(X + 1e-7, u_prev, Y_d + 1e-7, i_start)[1]
    far = Y_d + np.array([0.05, -0.03, 0.2])
    assert not screen.screened(X, u_prev, far, i_start)[1]  # a limit binds: the QP
    u, by_screen = screen.screened(X + 1e-7, u_prev, Y_d + 1e-7, i_start)
    assert not by_screen and u == full.solve(X + 1e-7, u_prev, Y_d + 1e-7, i_start)[0].tolist()
    assert screen.screened(X + 2e-7, u_prev, Y_d + 2e-7, i_start)[1]
