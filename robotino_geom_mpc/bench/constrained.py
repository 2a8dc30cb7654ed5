"""Benchmark ``constrained``: the constrained mode's step against the closed-form step and OSQP on the same QP.

Inputs (`constrained_inputs`), each a sequence of measured states and
previews the controller sees one after the other:

* ``paper-circle``: `controller_step.step_inputs` (the reference's states
  plus 10 um / 0.1 mm/s noise), the controller on the true model;
* ``robustness``: the same states with the robustness scenario's odometry
  noise (1 mm / 1 mrad on the pose) and its mismatched controller model;
* ``circle-step`` and ``position-step`` (limits bind): from rest, the
  paper's circle at full speed with no ramp-in (the paper's start, Fig. 6)
  and a step of (0.3 m, -0.2 m, 0.5 rad), the state moved by the MPC's own
  discrete model (eq. 49) under the commanded u, so the QP is solved at
  every tick of the transient.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from typing import Any, NamedTuple

import daqp
import numpy as np
import osqp
import scipy.sparse as sp

try:  # a test extra: the benchmark sets quadprog beside DAQP where it is installed
    import quadprog
except ImportError:  # pragma: no cover - depends on the installation
    quadprog = None

from robotino_geom_mpc.bench.controller_step import OSQP_TOLERANCES, step_inputs
from robotino_geom_mpc.bench.registry import BenchmarkError, benchmark
from robotino_geom_mpc.control.constrained import ConstrainedMPC
from robotino_geom_mpc.control.motion_controller import MotionController
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.reference.trajectories import CircleReference, preview
from robotino_geom_mpc.scenarios import get_scenario

__all__ = [
    "InputSet", "OsqpConstrainedQP", "QPCall", "bench_constrained", "constrained_inputs", "fastest_agreeing",
    "qp_arguments", "qp_calls",
]

NOMINAL_SETS = ("paper-circle", "robustness")
TRANSIENT_SETS = ("circle-step", "position-step")


class InputSet(NamedTuple):
    """Measured states (n, 6) and previews (n, N, 3) seen in order by a controller on `model`."""

    X: np.ndarray
    previews: np.ndarray
    model: RobotinoParams


def _model_run(model: RobotinoParams, control: ControlParams, previews: np.ndarray) -> InputSet:
    """States from rest moved by the MPC's discrete model (eq. 49) under the constrained controller's u."""
    controller = MotionController(model, replace(control, mode="constrained"))
    A_d, B_d = controller.mpc.A_d, controller.mpc.B_d
    x = np.zeros((3, 2))
    states = np.empty((len(previews), 6))
    for k, Y_d in enumerate(previews):
        states[k] = x.ravel()
        u = np.array(controller.step(states[k], Y_d).u)
        x = np.einsum("aij,aj->ai", A_d, x) + B_d * u[:, None]
    return InputSet(states, previews, model)


def constrained_inputs(steps: int, transient_steps: int = 100) -> dict[str, InputSet]:
    """The benchmark's input sets (see the module notes), `steps` ticks each for the nominal ones."""
    X, previews, robot, control = step_inputs(steps)
    spec = get_scenario("robustness")
    rng = np.random.default_rng(1)
    noisy = X.copy()
    noisy[:, 0::2] += rng.normal(0.0, [spec.noise.position_m, spec.noise.position_m, spec.noise.yaw_rad], (steps, 3))
    Ts, N = control.period_s, control.horizon
    circle = CircleReference(ramp_s=1e-3)  # full speed from the first tick, as the paper started
    start = circle.position(np.zeros(1))[0]
    circle_previews = np.stack([preview(circle, k * Ts, Ts, N) - start for k in range(transient_steps)])
    step_previews = np.tile(np.array([0.3, -0.2, 0.5]), (transient_steps, N, 1))
    return {
        "paper-circle": InputSet(X, previews, robot),
        "robustness": InputSet(noisy, previews, spec.controller_model(robot)),
        "circle-step": _model_run(robot, control, circle_previews),
        "position-step": _model_run(robot, control, step_previews),
    }


class QPCall(NamedTuple):
    """The arguments of one `ConstrainedMPC.solve` call, its u and whether its closed form met the limits."""

    X: np.ndarray
    u_prev: np.ndarray
    Y_d: np.ndarray
    i_start: np.ndarray
    u: np.ndarray
    closed_form: bool


class _RecordingQP(ConstrainedMPC):
    """`ConstrainedMPC` keeping the arguments and result of every `solve` or `solve_floats` (the controller's)."""

    def __init__(self, *args) -> None:
        super().__init__(*args)
        self.calls: list[QPCall] = []

    def solve(
        self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray
    ) -> tuple[np.ndarray, bool]:
        """`ConstrainedMPC.solve`, recorded."""
        u, infeasible = super().solve(X, u_prev, Y_d, i_start)
        self._record(X, u_prev, Y_d, i_start, u)
        return u, infeasible

    def solve_floats(
        self, X: Sequence[float], u_prev: Sequence[float], Y_d: Sequence[Sequence[float]], i_start: Sequence[float]
    ) -> tuple[list[float], bool]:
        """`ConstrainedMPC.solve_floats`, recorded."""
        u, infeasible = super().solve_floats(X, u_prev, Y_d, i_start)
        self._record(*(np.array(a, dtype=float) for a in (X, u_prev, Y_d, i_start, u)))
        return u, infeasible

    def _record(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray, u: np.ndarray) -> None:
        closed = bool(np.max(np.abs(self.closed_form_rows(X, u_prev, Y_d, i_start))) <= 1.0)
        self.calls.append(QPCall(X.copy(), u_prev.copy(), Y_d.copy(), i_start.copy(), u.copy(), closed))


def qp_calls(inputs: InputSet, control: ControlParams) -> list[QPCall]:
    """The constrained controller's QP calls over `inputs` (its own u(k-1), pose estimate and currents)."""
    controller = MotionController(inputs.model, replace(control, mode="constrained"))
    controller.constrained = recorder = _RecordingQP(inputs.model, controller.control, controller.mpc)
    for X, Y_d in zip(inputs.X, inputs.previews):
        controller.step(X, Y_d)
    return recorder.calls


def qp_arguments(qp: ConstrainedMPC, call: QPCall) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, G, h) of a call's QP min 1/2 z'Pz + f'z, |h + G z| <= 1 (`ConstrainedMPC.qp_problem`)."""
    _, f, h, G = qp.qp_problem(call.X, call.u_prev, call.Y_d, call.i_start)
    return f, G, h


class OsqpConstrainedQP:
    """The constrained mode's QP (`ConstrainedMPC.qp_problem`) for OSQP, set up once and warm-started.

    Like the DAQP model of `warm_qp.WarmDaqp`, OSQP is set up (its KKT matrix
    factored) once here, for the fixed P and the dense pattern of G; each
    `solve` updates the cost, the bounds and G's values and starts from the
    last solution. The defaults (tolerances 1e-12, no polishing) make it a
    reference for tests; the benchmark passes the loosest tolerance with
    polishing that still gives the same u (`fastest_agreeing`).

    Parameters
    ----------
    qp
        The constrained mode whose QP OSQP solves.
    eps
        OSQP's absolute and relative tolerance.
    polishing
        Whether OSQP polishes its solution (solves the KKT system of the active set it detects).
    """

    def __init__(self, qp: ConstrainedMPC, eps: float = 1e-12, polishing: bool = False) -> None:
        self.qp = qp
        m, n = 9 * qp.N, 3 * qp.N
        self._solver = osqp.OSQP()
        self._solver.setup(
            P=sp.csc_matrix(np.triu(qp._P)), q=np.zeros(n), A=sp.csc_matrix(np.ones((m, n))), l=-np.ones(m),
            u=np.ones(m), verbose=False, polishing=polishing, eps_abs=eps, eps_rel=eps, max_iter=20000,
        )
        self._zeros = np.zeros(n), np.zeros(m)
        self.reset()

    def reset(self) -> None:
        """Start the next solve from zero (primal and dual), as `ConstrainedMPC.reset` drops DAQP's active set."""
        self._solver.warm_start(x=self._zeros[0], y=self._zeros[1])

    def problem(self, call: QPCall) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f, G, h) of a call (`qp_arguments`)."""
        return qp_arguments(self.qp, call)

    def solve(self, f: np.ndarray, G: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Delta U of the QP min 1/2 z'Pz + f'z, |h + G z| <= 1; BenchmarkError unless solved."""
        self._solver.update(q=f, l=-1.0 - h, u=1.0 - h, Ax=G.ravel(order="F"))
        result = self._solver.solve(raise_error=False)
        if result.info.status_val != osqp.SolverStatus.OSQP_SOLVED:
            raise BenchmarkError(f"OSQP did not solve the constrained QP: {result.info.status}")
        return result.x


def fastest_agreeing(
    solvers: dict[str, ConstrainedMPC], calls: dict[str, list[QPCall]], problems: dict[str, list[tuple]]
) -> tuple[float, float]:
    """(eps, max u difference): the loosest OSQP tolerance with polishing whose u agree with all calls to 1e-6.

    One tolerance for all input sets, tried from 1e-3 down to 1e-10 (a looser
    OSQP is a faster peer); the difference is relative to max |u| (at least 1).

    Raises
    ------
    BenchmarkError
        If no tolerance agrees.
    """
    scale = max(1.0, max(float(np.abs(call.u).max()) for name in calls for call in calls[name]))
    for eps in OSQP_TOLERANCES:
        diff = 0.0
        for name, qp in solvers.items():
            reference = OsqpConstrainedQP(qp, eps=eps, polishing=True)
            for call, problem in zip(calls[name], problems[name]):
                diff = max(diff, float(np.abs(call.u_prev + reference.solve(*problem)[:3] - call.u).max()))
        if diff <= 1e-6 * scale:
            return eps, diff
    raise BenchmarkError(f"OSQP and the constrained step disagree on u by {diff:.3g} (scale {scale:.3g}), eps {eps:g}")


@contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence C-level writes to standard output (file descriptor 1) for the block.

    OSQP prints a line whenever polishing finds no active row, verbose or not.
    """
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _step_times(inputs: InputSet, control: ControlParams) -> np.ndarray:
    """Each tick's `MotionController.step` time [s] (its compute_time_s) over `inputs`, from reset."""
    controller = MotionController(inputs.model, control)
    return np.array([controller.step(X, Y_d).compute_time_s for X, Y_d in zip(inputs.X, inputs.previews)])


def _call_times(calls: list[QPCall], solve) -> np.ndarray:
    """Per-call wall times [s] of `solve(call)` over the calls, in order (warm starts carry over)."""
    times = np.empty(len(calls))
    for k, call in enumerate(calls):
        start = time.perf_counter()
        solve(call)
        times[k] = time.perf_counter() - start
    return times


def _paced_times(
    qp: ConstrainedMPC, reference: OsqpConstrainedQP, calls: list[QPCall], floats: list[tuple], period_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per-call times [s] of our step and the OSQP-based one, alternating, each after sleeping one period.

    The controller's own rhythm: a step starts after the process slept,
    with whatever the idle host did to the caches in between.
    """
    ours, theirs = np.empty(len(calls)), np.empty(len(calls))
    qp.reset()
    reference.reset()
    for k, (call, args) in enumerate(zip(calls, floats)):
        time.sleep(period_s)
        start = time.perf_counter()
        qp.solve_floats(*args)
        ours[k] = time.perf_counter() - start
        time.sleep(period_s)
        start = time.perf_counter()
        reference.solve(*reference.problem(call))
        theirs[k] = time.perf_counter() - start
    return ours, theirs


@benchmark("constrained", "constrained-mode step (closed form first, DAQP when a limit binds) vs closed form and OSQP")
@_quiet_stdout()  # OSQP's polishing prints
def bench_constrained(quick: bool) -> dict[str, float]:
    """Time the constrained mode's step against the closed-form step and against OSQP on the same QPs.

    Each tick's time is the median over interleaved repeats; then:

    * ``constrained_step_us``: median over the ticks of the paper-circle and
      robustness inputs of `MotionController.step` in constrained mode (its
      compute_time_s: the screen of `ConstrainedMPC.solve_floats`, the full
      check where the screen cannot decide, and the QP where a limit binds);
    * ``constrained_step_worst_us``: its slowest tick over all four input
      sets, the binding transients included;
    * ``constrained_over_closed_form``: median over the same nominal ticks of
      the per-tick ratio constrained step / closed-form step (the closed-form
      mode's `MotionController.step` on the same inputs);
    * ``constrained_step_speedup_vs_osqp``: median over the ticks where a
      limit binds (the QP ticks, all input sets) of the per-tick ratio OSQP
      step / our step, both on the controller's recorded calls: ours is
      `ConstrainedMPC.solve_floats`, the OSQP step builds the same rows and
      cost (`qp_problem`) and solves them with OSQP, set up once and
      warm-started, polishing, at the loosest tolerance whose u agree with
      ours to 1e-6 on every tick (`fastest_agreeing`; reported as
      ``constrained_osqp_eps``);
    * ``constrained_step_speedup_vs_osqp_worst``: the smallest of those
      per-tick ratios;
    * ``constrained_worst_speedup_vs_osqp``: OSQP's slowest tick over ours;
    * ``constrained_paced_binding_step_us``,
      ``constrained_paced_osqp_binding_step_us``,
      ``constrained_paced_speedup_vs_osqp``: the two steps on the binding
      ticks of the transients (circle-step, position-step) in the
      controller's rhythm, each after sleeping one control period (one pass:
      medians of ours, of OSQP's and of their per-tick ratio);
    * ``constrained_daqp_qp_us``, ``constrained_quadprog_qp_us`` (where
      quadprog is installed), ``constrained_osqp_qp_us``: the solvers alone
      on the built QPs of the binding ticks (DAQP and OSQP warm-started,
      quadprog cold: it has no warm start), medians.

    Raises
    ------
    BenchmarkError
        If OSQP's u differs from the constrained step's by more than 1e-6 (relative to max |u|, at least 1)
        at every tolerance tried.
    """
    steps, repeats = (200, 3) if quick else (1000, 7)
    sets = constrained_inputs(steps, transient_steps=50 if quick else 100)
    control = step_inputs(1)[3]
    constrained, closed = replace(control, mode="constrained"), replace(control, mode="closed_form")
    calls = {name: qp_calls(inputs, control) for name, inputs in sets.items()}
    solvers = {name: ConstrainedMPC(inputs.model, constrained, MotionController(inputs.model, constrained).mpc)
               for name, inputs in sets.items()}
    problems = {name: [qp_arguments(solvers[name], call) for call in calls[name]] for name in sets}
    floats = {name: [(c.X.tolist(), c.u_prev.tolist(), c.Y_d.tolist(), c.i_start.tolist()) for c in calls[name]]
              for name in sets}
    eps, diff = fastest_agreeing(solvers, calls, problems)
    osqp_qps = {name: OsqpConstrainedQP(solvers[name], eps=eps, polishing=True) for name in sets}

    def side_by_side(name: str) -> dict[str, np.ndarray]:
        """Per-call times of the constrained step's solve, an OSQP-based one and three QP solvers alone."""
        qp, reference, pending = solvers[name], osqp_qps[name], calls[name]
        qp.reset()
        args = iter(floats[name])
        times = {"step": _call_times(pending, lambda c: qp.solve_floats(*next(args)))}
        reference.reset()  # the same rows and cost, OSQP instead of DAQP: a constrained step built on OSQP
        times["osqp_step"] = _call_times(pending, lambda c: reference.solve(*reference.problem(c)))
        alone = _DenseDaqp(qp._P)
        dense = iter(problems[name])
        times["daqp"] = _call_times(pending, lambda c: alone.solve(*next(dense)))
        if quadprog is not None:
            dense = iter(problems[name])
            times["quadprog"] = _call_times(pending, lambda c: _quadprog_solve(qp._P, *next(dense)))
        reference.reset()
        dense = iter(problems[name])
        times["osqp"] = _call_times(pending, lambda c: reference.solve(*next(dense)))
        return times

    samples: dict[str, list[np.ndarray]] = {}
    for _ in range(repeats):
        rounds = {"constrained": np.concatenate([_step_times(sets[n], constrained) for n in sets]),
                  "closed": np.concatenate([_step_times(sets[n], closed) for n in NOMINAL_SETS])}
        solves = [side_by_side(name) for name in sets]
        rounds.update({key: np.concatenate([t[key] for t in solves]) for key in solves[0]})
        for key, value in rounds.items():
            samples.setdefault(key, []).append(value)
    paced = [_paced_times(solvers[n], osqp_qps[n], calls[n], floats[n], control.period_s) for n in TRANSIENT_SETS]
    tick = {key: np.median(np.stack(value), axis=0) for key, value in samples.items()}  # per tick over repeats
    nominal = tick["constrained"][: sum(len(sets[n].X) for n in NOMINAL_SETS)]
    binding = ~np.concatenate([[c.closed_form for c in calls[n]] for n in sets])
    speedup = tick["osqp_step"][binding] / tick["step"][binding]
    figures = {
        "constrained_step_us": float(np.median(nominal)) * 1e6,
        "constrained_step_worst_us": float(tick["constrained"].max()) * 1e6,
        "constrained_closed_form_step_us": float(np.median(tick["closed"])) * 1e6,
        "constrained_over_closed_form": float(np.median(nominal / tick["closed"])),
        "constrained_binding_step_us": float(np.median(tick["step"][binding])) * 1e6,
        "constrained_osqp_binding_step_us": float(np.median(tick["osqp_step"][binding])) * 1e6,
        "constrained_step_speedup_vs_osqp": float(np.median(speedup)),
        "constrained_step_speedup_vs_osqp_worst": float(np.min(speedup)),
        "constrained_worst_speedup_vs_osqp": float(tick["osqp_step"].max() / tick["step"].max()),
        "constrained_daqp_qp_us": float(np.median(tick["daqp"][binding])) * 1e6,
        "constrained_osqp_qp_us": float(np.median(tick["osqp"][binding])) * 1e6,
        "constrained_binding_ticks": float(binding.sum()),
        "constrained_osqp_max_u_difference": diff,
        "constrained_osqp_eps": eps,
    }
    paced_binding = ~np.array([c.closed_form for n in TRANSIENT_SETS for c in calls[n]])
    ours, theirs = (np.concatenate(times)[paced_binding] for times in zip(*paced))
    figures["constrained_paced_binding_step_us"] = float(np.median(ours)) * 1e6
    figures["constrained_paced_osqp_binding_step_us"] = float(np.median(theirs)) * 1e6
    figures["constrained_paced_speedup_vs_osqp"] = float(np.median(theirs / ours))
    if "quadprog" in tick:
        figures["constrained_quadprog_qp_us"] = float(np.median(tick["quadprog"][binding])) * 1e6
    return figures


class _DenseDaqp:
    """DAQP alone on the built QPs min 1/2 z'Pz + f'z, |h + G z| <= 1, warm-started from its last active set."""

    def __init__(self, P: np.ndarray) -> None:
        self.P = P
        self.model: Any = None  # a daqp.Model (daqp has no types) from the first solve on
        self.data: tuple[np.ndarray, np.ndarray] | None = None

    def solve(self, f: np.ndarray, G: np.ndarray, h: np.ndarray) -> np.ndarray:
        """z of the QP."""
        self.data = upper, lower = 1.0 - h, -1.0 - h  # DAQP keeps pointers: keep the arrays alive
        if self.model is None:
            self.model = daqp.Model()
            self.model.setup(self.P, f, G, upper, lower, np.zeros(len(h), dtype=np.int32))
        else:
            self.model.update(f=f, A=G, bupper=upper, blower=lower)
        return self.model.solve()[0]


def _quadprog_solve(P: np.ndarray, f: np.ndarray, G: np.ndarray, h: np.ndarray) -> np.ndarray:
    """quadprog (Goldfarb-Idnani dual active set, no warm start) on the same QP."""
    return quadprog.solve_qp(P, -f, np.vstack((-G, G)).T, np.concatenate((h - 1.0, -1.0 - h)))[0]
