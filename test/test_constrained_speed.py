"""Constrained mode's speed path: the QP only where a limit binds, DAQP's warm start, and the `constrained` benchmark.

No wall time is asserted: the work is counted (QP solves, active-set iterations)
and the benchmark's two sides must agree.
"""

from dataclasses import replace

import daqp
import numpy as np
import pytest

from robotino_geom_mpc.bench.constrained import bench_constrained, constrained_inputs, qp_calls
from robotino_geom_mpc.core.constrained import ConstrainedMPC
from robotino_geom_mpc.core.mpc import DecoupledMPC
from robotino_geom_mpc.core.params import load_params


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


def test_benchmark_reports_its_figures_with_osqp_agreeing():
    figures = bench_constrained(quick=True)
    for key in ("constrained_step_us", "constrained_step_worst_us", "constrained_step_speedup_vs_osqp",
                "constrained_over_closed_form"):
        assert np.isfinite(figures[key]) and figures[key] > 0.0
    assert figures["constrained_step_worst_us"] >= figures["constrained_step_us"]
    assert 0.0 < figures["constrained_step_speedup_vs_osqp_worst"] <= figures["constrained_step_speedup_vs_osqp"]
    assert figures["constrained_osqp_max_u_difference"] <= 1e-6 * 10.0  # |u| reaches ~10 m/s^2 in the position step
    assert figures["constrained_binding_ticks"] >= 10
