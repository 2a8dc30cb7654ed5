"""`robotino-geom-mpc bench`: the JSON line, the registry, the OSQP side's QP, the CDR benchmark's sides and ratios.

Only structure and sanity are checked (keys present, values positive and
finite); no test asserts a speed.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from robotino_geom_mpc.bench import registry as benchmarks
from robotino_geom_mpc.bench import BenchmarkError, BenchmarkSkipped, benchmark, run_benchmarks
from robotino_geom_mpc.bench.controller_step import OsqpMPC
from robotino_geom_mpc.cli import main
from robotino_geom_mpc.control.mpc import DecoupledMPC
from robotino_geom_mpc.params.files import load_params

pytestmark = pytest.mark.ros



@pytest.mark.parametrize("stacked", [False, True])
def test_osqp_qp_is_the_closed_form_mpc_problem(stacked):
    """The QPs OSQP solves have the closed form (eq. 56) as their minimiser, whole horizon."""
    robot, control = load_params()
    mpc = DecoupledMPC(robot, control)
    qp = OsqpMPC(mpc, stacked=stacked)
    N = mpc.horizon
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = rng.normal(0.0, 0.1, (3, 2))
        u_prev = rng.normal(0.0, 1.0, 3)
        Y_d = rng.normal(0.0, 0.01, (N, 3))
        whole = []
        for solver, q in zip(qp.solvers, qp.linear_terms(x, u_prev, Y_d)):
            solver.update(q=q)
            whole.append(solver.solve(raise_error=False).x)
        dU = np.concatenate(whole).reshape(3, N).T
        closed = mpc.solve(x, u_prev, Y_d)
        np.testing.assert_allclose(dU, closed, rtol=0, atol=1e-8 * np.abs(closed).max())
        # and the first increment is what the receding-horizon law applies
        np.testing.assert_allclose(qp.solve(qp.linear_terms(x, u_prev, Y_d)), closed[0],
                                   atol=1e-8 * np.abs(closed).max())


@pytest.fixture
def registry(monkeypatch):
    fresh: dict = {}
    monkeypatch.setattr(benchmarks, "REGISTRY", fresh)
    return fresh


def test_adding_a_benchmark_is_one_registered_function(registry):
    @benchmark("first", "returns one figure")
    def first(quick):
        return {"a_figure": 2.0 if quick else 3.0}

    @benchmark("no_ros", "cannot run here")
    def no_ros(quick):
        raise BenchmarkSkipped("no DDS")

    lines = []
    assert run_benchmarks(quick=True, log=lines.append) == {"a_figure": 2.0}
    assert run_benchmarks(quick=False, log=lines.append) == {"a_figure": 3.0}
    assert any("skipped (no DDS)" in line for line in lines)
    with pytest.raises(ValueError, match="twice"):
        benchmark("first", "again")(first)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -1.0, "fast"])
def test_benchmark_with_bad_figure_fails(registry, value):
    benchmark("bad", "bad figure")(lambda quick: {"figure": value})
    with pytest.raises(BenchmarkError, match="figure"):
        run_benchmarks(log=lambda line: None)


def test_unknown_benchmark_name(registry, capsys):
    benchmark("known", "ok")(lambda quick: {"x": 1.0})
    with pytest.raises(BenchmarkError, match="unknown benchmark nope"):
        run_benchmarks(names=["nope"], log=lambda line: None)
    assert main(["bench", "--only", "nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown benchmark nope" in err and "known" in err


def test_a_soak_runs_only_by_name_and_takes_the_duration(registry, capsys):
    benchmark("plain", "always")(lambda quick: {"x": 1.0})

    @benchmark("long", "only by name", default=False, takes_duration=True)
    def long(quick, duration_s=None):
        return {"long_s": 30.0 if duration_s is None else duration_s}

    assert run_benchmarks(log=lambda line: None) == {"x": 1.0}  # a plain bench leaves it out
    assert run_benchmarks(names=["long"], log=lambda line: None) == {"long_s": 30.0}
    assert run_benchmarks(names=["long", "plain"], duration_s=5.0, log=lambda line: None) == {"long_s": 5.0, "x": 1.0}
    assert main(["bench", "--only", "controller_step", "--duration", "5"]) == 2  # none of these takes one
    assert "--duration needs --only with a benchmark that takes one (soak)" in capsys.readouterr().err


def test_failed_benchmark_exits_1_with_one_line(registry, capsys):
    def broken(quick):
        raise BenchmarkError("sides disagree")

    benchmark("broken", "fails")(broken)
    assert main(["bench", "--json"]) == 1
    err = capsys.readouterr().err
    assert "sides disagree" in err and "Traceback" not in err


def test_dds_benchmark_skipped_without_ros(monkeypatch):
    monkeypatch.setitem(sys.modules, "robotino_geom_mpc.bench.dds", None)  # import fails
    lines = []
    assert run_benchmarks(quick=True, names=["dds"], log=lines.append) == {}
    assert "skipped" in lines[-1]




@pytest.mark.parametrize("break_side, reason", [("values", "read different values"), ("message", "differ")])
def test_cdr_benchmark_fails_when_its_sides_disagree(monkeypatch, break_side, reason):
    """A reader that returns other values, or a built message other than the template's, is caught before timing."""
    from robotino_geom_mpc.bench import cdr as cdr_bench
    from robotino_geom_mpc.ros.messages import three_values

    cases = cdr_bench.message_cases

    def broken(period_s):
        out = cases(period_s)
        voltages = out["wheel_voltages"]
        if break_side == "values":
            voltages["values"] = lambda msg: tuple(msg.data)[::-1]
        else:
            voltages["message"] = three_values("another_label")  # same numbers, other layout label
        return out

    monkeypatch.setattr(cdr_bench, "message_cases", broken)
    with pytest.raises(BenchmarkError, match=f"cdr wheel_voltages: .*{reason}"):
        cdr_bench.bench_cdr(quick=True)


def test_fleet_batch_benchmark_gives_each_size_and_fails_when_the_batch_disagrees(monkeypatch):
    """The batched step equals the robots' own steps (checked before timing); a batch off by 1e-6 V is caught."""
    from robotino_geom_mpc.bench import fleet_batch
    from robotino_geom_mpc.control.motion_batch import MotionControllerBatch

    figures = fleet_batch.bench_fleet_batch(quick=True)
    for size in fleet_batch.FLEET_SIZES:
        each, batched = figures[f"fleet_batch_{size}_one_at_a_time_us"], figures[f"fleet_batch_{size}_batched_us"]
        assert np.isfinite([each, batched]).all() and each > 0 and batched > 0
        assert figures[f"fleet_batch_{size}_one_at_a_time_over_batched"] == pytest.approx(each / batched)
    step = MotionControllerBatch.step
    monkeypatch.setattr(MotionControllerBatch, "step", lambda self, X, preview: (step(self, X, preview)[0] + 1e-6,
                                                                                None))
    with pytest.raises(BenchmarkError, match="B = 1: the batched voltages differ by 1e-06 V"):
        fleet_batch.bench_fleet_batch(quick=True)
