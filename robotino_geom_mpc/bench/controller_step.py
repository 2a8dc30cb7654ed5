"""Benchmark ``controller_step``: `MotionController.step` against OSQP solving the same MPC problems side by side."""

from __future__ import annotations

from typing import Callable

import numpy as np
import osqp
import scipy.sparse as sp

from robotino_geom_mpc.bench.registry import BenchmarkError, benchmark, median_per_call
from robotino_geom_mpc.control.motion_controller import MotionController
from robotino_geom_mpc.control.mpc import DecoupledMPC
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference, preview

__all__ = ["OSQP_TOLERANCES", "OsqpMPC", "bench_controller_step", "step_inputs"]

# OSQP's tolerances tried loosest first for a benchmark's peer: the loosest whose u agrees to 1e-6 is the fastest
OSQP_TOLERANCES = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-10)


def step_inputs(steps: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, RobotinoParams, ControlParams]:
    """Measured states and previews of `steps` ticks along paper-circle from rest.

    The states are the reference's plus 10 um / 0.1 mm/s noise, what a
    well-tracking closed loop measures (no voltage saturation).
    """
    robot, control = load_params()
    reference = make_reference("paper-circle")
    rng = np.random.default_rng(seed)
    Ts, N = control.period_s, control.horizon
    times = np.arange(steps) * Ts
    pos, vel, _, _ = reference.sample(times)
    X = np.empty((steps, 6))
    X[:, 0::2] = pos + rng.normal(0.0, 1e-5, size=pos.shape)
    X[:, 1::2] = vel + rng.normal(0.0, 1e-4, size=vel.shape)
    previews = np.stack([preview(reference, t, Ts, N) for t in times])
    return X, previews, robot, control


class OsqpMPC:
    """The three per-axis MPC problems of one step for OSQP (warm-started, absolute and relative tolerance `eps`).

    Per axis a, variables Delta U_a = Delta u_a(k..k+N-1); cost
    1/2 Delta U_a^T (F_1p^T Q_p F_1p + R_p) Delta U_a - Delta U_a^T F_1p^T Q_p e_a,
    e = Y_d - G_p x(k) - F_2p u(k-1) (eqs. 50-54), whose minimiser is eq. (56).
    `stacked=False` solves the three as the paper poses them, one OSQP problem
    per axis; `stacked=True` as one block-diagonal QP (one call instead of three).
    """

    def __init__(self, mpc: DecoupledMPC, stacked: bool, eps: float = 1e-10) -> None:
        self.mpc = mpc
        self.N = mpc.horizon
        hessians = [sp.csc_matrix(np.triu(h)) for h in mpc.hessian]
        blocks = [sp.block_diag(hessians, format="csc")] if stacked else hessians
        self._lin = [mpc.q[a] * mpc.F_1p[a].T for a in range(3)]
        self.solvers = []
        for P in blocks:
            solver = osqp.OSQP()
            n = P.shape[0]
            solver.setup(
                P=P, q=np.zeros(n), A=sp.csc_matrix((0, n)), l=np.zeros(0), u=np.zeros(0),
                eps_abs=eps, eps_rel=eps, max_iter=100000, polishing=False, warm_starting=True, verbose=False,
            )
            self.solvers.append(solver)
        self._solved = osqp.SolverStatus.OSQP_SOLVED

    def linear_terms(self, x: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray) -> list[np.ndarray]:
        """The linear cost terms, one per solver."""
        e = self.mpc.free_error(x, u_prev, Y_d)  # (N, 3)
        q = [-(self._lin[a] @ e[:, a]) for a in range(3)]
        return [np.concatenate(q)] if len(self.solvers) == 1 else q

    def solve(self, q_terms: list[np.ndarray]) -> np.ndarray:
        """Delta u(k) of the three axes for the linear terms of `linear_terms`."""
        first = []
        for solver, q in zip(self.solvers, q_terms):
            solver.update(q=q)
            result = solver.solve(raise_error=False)
            if result.info.status_val != self._solved:
                raise BenchmarkError(f"OSQP did not solve the MPC QP: {result.info.status}")
            first.append(result.x[:: self.N])
        return np.concatenate(first)


@benchmark("controller_step", "MotionController.step (MPCs + T(theta) + inverse drive) vs OSQP on the same MPC QPs")
def bench_controller_step(quick: bool) -> dict[str, float]:
    """Time the controller's step against OSQP on identical per-step MPC problems.

    The controller runs first over a sequence of measured states and previews
    along paper-circle; OSQP then solves the MPC problems of the same steps
    (three per-axis QPs, and one stacked QP) with the states, previews and
    u(k-1) the controller saw. OSQP's time counts the per-step MPC work of a
    controller built on it (the linear term from the state and the preview,
    `update`, `solve`) while the controller's covers the whole step, pose
    filter, T(theta) and inverse drive included, so
    ``controller_step_speedup_vs_osqp`` is a lower bound on the speed-up over
    a controller built on OSQP; ``closed_form_mpc_speedup_vs_osqp`` compares
    the MPC parts alone.

    OSQP runs at the loosest of `OSQP_TOLERANCES` whose u agree with the
    controller's to 1e-6 (relative to max |u|, at least 1) on every step,
    reported as ``osqp_mpc_eps``: a tighter OSQP is only slower.

    Raises
    ------
    BenchmarkError
        If OSQP's u(k) = u(k-1) + Delta u(k) differs from the controller's u at every tolerance.
    """
    steps, repeats = (200, 3) if quick else (1000, 7)
    X, previews, robot, control = step_inputs(steps)
    controller = MotionController(robot, control)

    # the controller's own u(k-1) (after its anti-windup) and pose estimate are the inputs both sides see
    u_prev = np.empty((steps, 3))
    u_ctrl = np.empty((steps, 3))
    X_used = X.copy()
    controller.reset()
    for k in range(steps):
        u_prev[k] = controller.u_prev
        u_ctrl[k] = controller.step(X[k], previews[k]).u
        if controller.estimator is not None:
            X_used[k, 0::2] = controller.estimator.estimate

    def controller_pass() -> None:
        controller.reset()
        for k in range(steps):
            controller.step(X[k], previews[k])

    mpc = DecoupledMPC(robot, control)
    scale = max(1.0, float(np.abs(u_ctrl).max()))
    for eps in OSQP_TOLERANCES:  # the loosest OSQP whose u agree with the controller's to 1e-6
        solvers = {"per_axis": OsqpMPC(mpc, stacked=False, eps=eps), "stacked": OsqpMPC(mpc, stacked=True, eps=eps)}
        q_terms = {
            name: [qp.linear_terms(X_used[k].reshape(3, 2), u_prev[k], previews[k]) for k in range(steps)]
            for name, qp in solvers.items()
        }
        diff = 0.0
        for name, qp in solvers.items():
            u_osqp = np.array([u_prev[k] + qp.solve(q_terms[name][k]) for k in range(steps)])
            diff = max(diff, float(np.abs(u_osqp - u_ctrl).max()))
        if diff <= 1e-6 * scale:
            break
    else:
        raise BenchmarkError(f"OSQP and the controller disagree on u by {diff:.3g} (scale {scale:.3g}), eps {eps:g}")

    states = X_used.reshape(steps, 3, 2)

    def osqp_pass(name: str) -> Callable[[], None]:
        qp = solvers[name]

        def run() -> None:  # the per-step MPC work of an OSQP-based controller: linear term, update, solve
            for k in range(steps):
                qp.solve(qp.linear_terms(states[k], u_prev[k], previews[k]))

        return run

    floats = X_used.tolist(), u_prev.tolist(), [p.tolist() for p in previews]  # as the controller's step has them

    def closed_form_pass() -> None:
        for X_k, u_k, preview_k in zip(*floats):
            mpc.delta_u(X_k, u_k, preview_k)

    ctrl_s, per_axis_s, stacked_s, closed_s = median_per_call(
        [controller_pass, osqp_pass("per_axis"), osqp_pass("stacked"), closed_form_pass], steps, repeats
    )
    return {
        "controller_step_us": ctrl_s * 1e6,
        "osqp_mpc_solve_us": per_axis_s * 1e6,
        "osqp_stacked_mpc_solve_us": stacked_s * 1e6,
        "closed_form_mpc_us": closed_s * 1e6,
        "controller_step_speedup_vs_osqp": per_axis_s / ctrl_s,
        "controller_step_speedup_vs_osqp_stacked": stacked_s / ctrl_s,
        "closed_form_mpc_speedup_vs_osqp": per_axis_s / closed_s,
        "osqp_max_u_difference": diff,
        "osqp_mpc_eps": eps,
        "controller_steps_timed": float(steps),
    }
