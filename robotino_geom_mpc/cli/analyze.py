"""`robotino-geom-mpc analyze`: subspaces, decoupling check, functional-controllability orders, the paper's errata."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.linalg import expm
from scipy.optimize import brentq

from robotino_geom_mpc.cli import VERBS, UsageError
from robotino_geom_mpc.geometric.decoupling import B_decoupled, DecouplingField, check_decoupling
from robotino_geom_mpc.geometric.functional import functional_controllability
from robotino_geom_mpc.model.dynamics import acceleration_block, g_theta
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file

__all__ = ["add_parser", "run", "printed_acceleration_block", "body_frame_turn", "errata", "build_report"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = sub.add_parser(
        "analyze",
        help=VERBS["analyze"],
        description=(
            "Subspace dimensions of Section III, T(theta) and conditions (12)-(21) over a theta grid "
            "that includes pi/2 + k pi, functional-controllability orders (Section IV) by two routes, "
            "and the paper's errata with a computed figure each. Exit status 1 if a decoupling check fails."
        ),
    )
    parser.add_argument("--params", metavar="FILE", help="ROS 2 parameter file (default: the Robotino 3 preset)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the report")
    parser.add_argument("--n-theta", type=int, default=3600, metavar="N",
                        help="grid points over [-pi, pi] (default 3600)")
    parser.set_defaults(func=run)
    return parser


def printed_acceleration_block(theta: float, p: RobotinoParams) -> np.ndarray:
    """Rows 2, 4, 6 of g(theta) exactly as eq. (9) prints them (erratum 1: the angular row)."""
    M, J, l, a = p.M, p.J, p.l, 2.0 * np.pi / 3.0
    s, c = np.sin, np.cos
    th = theta
    return np.array(
        [
            [s(th) / M, s(a + th) / M, -s(a - th) / M],
            [c(th) / M, c(a + th) / M, c(a - th) / M],
            [
                (s(th) * l * s(th) + c(th) * l * c(th)) / J,
                (s(a + th) * l * c(np.pi / 6 + th) + c(a + th) * l * s(np.pi / 6 + th)) / J,
                (-s(a - th) * l * c(np.pi / 6 - th) + c(a - th) * l * s(np.pi / 6 - th)) / J,
            ],
        ]
    )


def body_frame_turn(block, theta: float, forces: np.ndarray) -> float:
    """Angle [rad] by which the body-frame acceleration of fixed wheel forces turns from heading 0 to theta.

    Parameters
    ----------
    block
        theta -> the (3, 3) acceleration block (rows 2, 4, 6 of g(theta), eq. 9) of a model.
    forces
        Wheel forces F [N], held.

    Notes
    -----
    The odom-frame acceleration (x'', y'') is turned into base_link by R(theta)^T
    (REP-103: yaw counter-clockwise); a rigid robot's is the same at every heading.
    """

    def body(t: float) -> np.ndarray:
        a, c, s = block(t)[:2] @ forces, np.cos(t), np.sin(t)
        return np.array([c * a[0] + s * a[1], c * a[1] - s * a[0]])

    b0, b = body(0.0), body(theta)
    return float(np.arctan2(b0[0] * b[1] - b0[1] * b[0], b0 @ b))


def _sign_changes(f, grid: np.ndarray) -> list[float]:
    values = np.array([f(t) for t in grid])
    roots = []
    for k in np.nonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0)[0]:
        roots.append(float(brentq(f, grid[k], grid[k + 1], xtol=1e-12)))
    return roots


def _x_axis_discrete(p: RobotinoParams, period_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of the x block of eq. (4) with input x'' (B of eq. 37)."""
    Ac = np.array([[0.0, 1.0], [0.0, -p.k_x / p.M]])
    Bc = np.array([[0.0], [1.0]])
    E = expm(np.block([[Ac, Bc], [np.zeros((1, 3))]]) * period_s)
    return E[:2, :2], E[:2, 2:], np.array([[1.0, 0.0]])


def errata(p: RobotinoParams, control: ControlParams) -> list[dict]:
    """Errata 1-5 of ROBOTINO_NOTES.md and 6 (handedness), each with a figure computed from the parameters."""
    grid = np.linspace(-np.pi, np.pi, 721)
    printed_det = lambda t: float(np.linalg.det(printed_acceleration_block(t, p)))  # noqa: E731
    dets = np.array([np.linalg.det(acceleration_block(t, p)) for t in grid])
    roots = _sign_changes(printed_det, grid)
    near = min(roots, key=abs) if roots else None

    conds = {f"{t:.4f}": float(np.linalg.cond(acceleration_block(t, p))) for t in (-np.pi / 2, 0.0, np.pi / 2)}
    field = DecouplingField(p)
    sing_res = max(float(np.max(np.abs(g_theta(t, p) @ field.field(t) - B_decoupled())))
                   for t in (-np.pi / 2, np.pi / 2))

    Ad, Bd, H = _x_axis_discrete(p, control.period_s)
    N = control.horizon
    sim, x, printed, corrected = [], np.zeros((2, 1)), [], []
    for j in range(1, N + 1):
        x = Ad @ x + Bd  # u(k-1) = 1 held, Delta u = 0, x(k) = 0
        sim.append(float((H @ x)[0, 0]))
        powers = [np.linalg.matrix_power(Ad, i) for i in range(j)]
        corrected.append(float((H @ sum(powers) @ Bd)[0, 0]))
        printed_sum = H @ Bd if j == 1 else H @ sum(powers[i] + np.eye(2) for i in range(1, j)) @ Bd
        printed.append(float(printed_sum[0, 0]))
    sim_a = np.array(sim)
    rel = lambda v: float(np.max(np.abs(np.array(v) - sim_a)) / np.max(np.abs(sim_a)))  # noqa: E731

    # 6: fixed forces of a forward push (T(0) (1, 0, 0)), the heading turned by 0.5 rad
    forward, spin, theta6 = field.field(0.0)[:, 0], field.field(0.0)[:, 2], 0.5
    turn_printed = body_frame_turn(lambda t: printed_acceleration_block(t, p), theta6, forward)
    turn_corrected = body_frame_turn(lambda t: acceleration_block(t, p), theta6, forward)
    spin_acc = acceleration_block(theta6, p) @ field.field(theta6)[:, 2]  # u = (0, 0, +1 rad/s^2)
    k_F_paper = p.torque_constant_n_m_per_a / p.r
    k_F = p.gear_ratio * k_F_paper
    return [
        {
            "id": 1,
            "title": "g(theta) angular row, eq. (9)",
            "printed_det_zero_crossings_rad": roots,
            "printed_det_zero_nearest_0_rad": near,
            "corrected_det_min": float(dets.min()),
            "corrected_det_max": float(dets.max()),
            "summary": (
                (f"printed acceleration block singular at theta = {near:.4f} rad " if roots
                 else "printed block regular ")
                + f"({len(roots)} zero crossings over [-pi, pi]); corrected row (l/J, l/J, l/J): "
                f"det constant {dets.mean():.6e} (spread {np.ptp(dets):.1e})"
            ),
        },
        {
            "id": 2,
            "title": "singularities at pi/2 + k pi (text after eq. 28)",
            "condition_number_by_theta": conds,
            "decoupling_residual_at_pi_2": sing_res,
            "summary": (
                f"cond(G3) = {conds[f'{np.pi / 2:.4f}']:.4f} at pi/2, {conds['0.0000']:.4f} at 0; "
                f"|g T - B| at +-pi/2 = {sing_res:.1e}: no singularity"
            ),
        },
        {
            "id": 3,
            "title": "F_1p and F_2p sums, eqs. (52)-(53)",
            "f2p_printed": printed,
            "f2p_corrected": corrected,
            "f2p_simulated": sim,
            "printed_rel_error": rel(printed),
            "corrected_rel_error": rel(corrected),
            "summary": (
                f"x axis, Ts = {control.period_s:g} s, N = {N}: printed F_2p off the step-by-step "
                f"simulation by {rel(printed):.1%}, H (I + ... + A^(j-1)) B by {rel(corrected):.1e}"
            ),
        },
        {
            "id": 4,
            "title": "F = Km i / r omits the gear ratio",
            "force_per_ampere_paper_n": k_F_paper,
            "force_per_ampere_n": k_F,
            "summary": (
                f"{k_F_paper:.3f} N/A without the {p.gear_ratio:g}:1 gear vs {k_F:.3f} N/A with it; "
                f"at the nominal {p.nominal_current_a:g} A a wheel pushes {k_F * p.nominal_current_a:.2f} N, "
                f"not {k_F_paper * p.nominal_current_a:.3f} N"
            ),
        },
        {
            "id": 5,
            "title": "performance index (54) penalises Delta u(k+1) ... Delta u(k+N)",
            "decision_moves": N,
            "penalised_decision_moves_printed": N - 1,
            "summary": (
                f"of the {N} decision moves Delta u(k) ... Delta u(k+{N - 1}), the printed index penalises "
                f"{N - 1}, leaves the applied move Delta u(k) free and penalises Delta u(k+{N}), "
                f"not a decision variable"
            ),
        },
        {
            "id": 6,
            "title": "handedness of g(theta), rows 2 and 4 of eq. (9)",
            "theta_rad": theta6,
            "body_acceleration_turn_printed_rad": turn_printed,
            "body_acceleration_turn_corrected_rad": turn_corrected,
            "rotation_command_acceleration": spin_acc.tolist(),
            "rotation_pattern_forces_n": spin.tolist(),
            "summary": (
                f"fixed wheel forces at theta = {theta6:g} rad: the body-frame acceleration turns by "
                f"{turn_printed:+.4f} rad with d_i(theta) = R(-theta) d_i(0) as printed (-2 theta: the wheels turn "
                f"clockwise while the yaw turns counter-clockwise), by {turn_corrected:+.1e} rad with "
                f"R(theta) d_i(0) (REP-103); a rotation command u_theta = +1 rad/s^2 gives theta'' = "
                f"{spin_acc[2]:+.4f} rad/s^2 and no translation ({np.hypot(*spin_acc[:2]):.0e} m/s^2): "
                "the yaw increases, counter-clockwise in RViz"
            ),
        },
    ]


def build_report(robot: RobotinoParams, control: ControlParams, params_file: Path, n_theta: int = 3600) -> dict:
    """Everything `analyze` prints, as one JSON-serialisable dict."""
    dec = check_decoupling(robot, n_theta=n_theta)
    fc = functional_controllability(robot)
    return {
        "params_file": str(params_file),
        "subspace_dimensions": dec.dimensions,
        "theta_grid_points": dec.theta_grid_points,
        "singular_points_included": dec.singular_points_included,
        "decoupling_max_residual": dec.max_residual,
        "decoupling_worst_theta": dec.worst_theta,
        "fast_vs_toolbox_rel": dec.fast_vs_toolbox_rel,
        "decoupling_passed": dec.passed,
        "conditions": [asdict(c) for c in dec.conditions],
        "T0": DecouplingField(robot).T0.tolist(),
        "functional_controllability_order": fc["orders"],
        "functional_controllability_details": fc["details"],
        "errata": errata(robot, control),
    }


def _text(report: dict) -> str:
    lines = [f"parameters: {report['params_file']}", "", "subspace dimensions (Section III, 9 angles incl. +-pi/2):"]
    lines += [f"  {name:48s} {d}" for name, d in report["subspace_dimensions"].items()]
    lines += [
        "",
        f"decoupling field T(theta) over {report['theta_grid_points']} angles in [-pi, pi] "
        f"(pi/2 + k pi included: {'yes' if report['singular_points_included'] else 'no'}):",
        f"  max |g(theta) T(theta) - B|   {report['decoupling_max_residual']:.3e}  "
        f"(worst theta {report['decoupling_worst_theta']:.4f} rad)",
        f"  fast path vs toolbox (rel.)  {report['fast_vs_toolbox_rel']:.3e}",
    ]
    for c in report["conditions"]:
        verdict = 'ok' if c['passed'] else 'FAIL'
        lines.append(f"  {c['equation']:5s} {c['statement']:34s} {c['measure']:28s} {c['value']:.3e}  {verdict}")
    lines += ["", "functional-controllability order (eq. 38 projection / Markov parameters):"]
    details = report["functional_controllability_details"]
    for part, cases in (("mechanical", details["mechanical"]), ("drive", details["drive"])):
        for case, o in cases.items():
            lines.append(f"  {part:10s} {case:22s} {o['projection']} / {o['markov']}")
    for theta, cases in details["cascade"].items():
        summary = ", ".join(f"{case} {o['projection']}/{o['markov']}" for case, o in cases.items())
        lines.append(f"  cascade    theta = {theta:9s}   {summary}")
    orders = report["functional_controllability_order"]
    lines.append("  orders: " + ", ".join(f"{k} {v}" for k, v in orders.items()))
    lines += ["", "paper errata corrected by the model:"]
    lines += [f"  {e['id']}. {e['title']}: {e['summary']}" for e in report["errata"]]
    lines.append("")
    lines.append("decoupling checks: " + ("all passed" if report["decoupling_passed"] else "FAILED"))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.n_theta < 2:
        raise UsageError(f"--n-theta must be >= 2, got {args.n_theta}")
    path = Path(args.params) if args.params else default_params_file()
    robot, control = load_params(path)
    report = build_report(robot, control, path, n_theta=args.n_theta)
    print(json.dumps(report) if args.json else _text(report))
    return 0 if report["decoupling_passed"] else 1
