"""Constrained mode (beyond the paper): the MPC cost (54) as a QP with wheel current and voltage limits.

The three axes share the wheels: currents i = (r / (gear Km)) T(theta) u
and voltages U = R i + L_d (i - i_0)/Ts + Km (omega + t_e omega') (see
`drive`) mix u_x, u_y, u_theta, so the limits |i| <= i_nom and |U| <= U_supply
couple the three per-axis problems into one QP over
Delta U = (Delta u(k), ..., Delta u(k+N-1)) for all axes (3N variables).

Over the horizon every quantity is affine in Delta U: the inputs (eq. 48),
the velocities of the discrete model (eq. 49), the motor speeds and their
rates (for a fixed heading), the currents, the voltages and the drive's
predicted start currents (`drive.ZOHDrive`, whose relations are linear).
The heading is the measured one for the first period (at mid-period, as the
controller applies it) and the reference's for the later ones.

When the closed form (56) already meets every limit it is the QP's optimum
and is returned as is. Otherwise the solver is OSQP: the package's runtime
dependency already, well maintained, warm-started from the previous period's
solution, with tight tolerances (it matches the closed form to 1e-9 when no
limit is active) and solution polishing on the active set, and with
infeasibility certificates. When the limits cannot all hold, the least total
violation is found by a linear programme (scipy's HiGHS), the limits are
relaxed by exactly that much and the QP solved again: the output stays
finite, the violation is the smallest possible, and the step reports
`infeasible`.
"""

from __future__ import annotations

import math

import numpy as np
import osqp
import scipy.sparse as sp
from scipy.optimize import linprog

from .decoupling import DecouplingField
from .drive import MotorKinematics, ZOHDrive
from .mpc import DecoupledMPC, axis_dampings
from .params import ControlParams, RobotinoParams

__all__ = ["ConstrainedMPC"]

_SOLVED = int(osqp.SolverStatus.OSQP_SOLVED)
_VIOLATION_TOL = 1e-6  # relative to the limit: larger slack means infeasible


def _rotation(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class ConstrainedMPC:
    """The three MPCs of Section V as one QP with wheel current and voltage limits.

    Parameters
    ----------
    robot
        Controller's robot model (T(theta), drive, limits `nominal_current_a`, `supply_voltage_v`).
    control
        Period and horizon.
    mpc
        The unconstrained MPCs whose cost (Hessian F_1p^T Q_p F_1p + R_p) the QP minimises.

    Notes
    -----
    Decision vector z with z[3 j + a] = Delta u_a(k + j). Constraint rows,
    scaled by their limits, for the wheels w and j = 0..N-1: the period
    averages -1 <= i_w(k+j) / i_nom <= 1 (what moves the robot), the same for
    the currents at the period ends (the current relaxes exponentially from
    one end value towards the next, so with the averages this bounds it along
    the whole period up to a hump of about 1 % where the back-EMF rises
    within the period) and -1 <= U_w(k+j) / U_supply <= 1.
    """

    def __init__(self, robot: RobotinoParams, control: ControlParams, mpc: DecoupledMPC) -> None:
        self.mpc = mpc
        self.N = int(control.horizon)
        self.period_s = float(control.period_s)
        self.zoh = ZOHDrive(robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a, self.period_s)
        self.kinematics = MotorKinematics(robot)
        self._T0 = DecouplingField(robot).T0
        self._force_to_current = robot.r / (robot.gear_ratio * robot.torque_constant_n_m_per_a)
        self._damping = axis_dampings(robot)
        self.nominal_current_a = robot.nominal_current_a
        self.supply_voltage_v = robot.supply_voltage_v
        N, nz = self.N, 3 * self.N
        P = np.zeros((nz, nz))
        for a in range(3):
            P[a::3, a::3] = mpc.hessian[a]
        self._scale = 1.0 / float(np.max(np.diag(P)))
        self._P = P * self._scale
        self._nrows = 9 * N
        self._solver: osqp.OSQP | None = None

    def reset(self) -> None:
        """Drop the warm start."""
        self._solver = None

    def _linear_cost(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray) -> np.ndarray:
        e = self.mpc.free_error(X.reshape(3, 2), u_prev, Y_d)  # (N, 3)
        f = np.empty(3 * self.N)
        for a in range(3):
            f[a::3] = -self.mpc.q[a] * self.mpc.F_1p[a].T @ e[:, a]
        return f * self._scale

    def constraint_rows(
        self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Currents and voltages over the horizon as affine functions of z.

        Returns
        -------
        currents, end_currents, voltages : ndarray, shape (N, 3, 1 + 3N)
            Period-average currents, currents at the end of each period and
            voltages; column 0 the constant part, the rest the coefficients of z.
        scaled : ndarray, shape (9N, 1 + 3N)
            All rows divided by their limits.
        """
        N, nz, Ts = self.N, 3 * self.N, self.period_s
        A_d, B_d = self.mpc.A_d, self.mpc.B_d
        theta, w = float(X[4]), float(X[5])
        u = np.zeros((3, 1 + nz))
        u[:, 0] = u_prev
        v = np.zeros((3, 1 + nz))
        v[:, 0] = X[1::2]
        i0 = np.zeros((3, 1 + nz))
        i0[:, 0] = i_start
        currents = np.empty((N, 3, 1 + nz))
        ends = np.empty((N, 3, 1 + nz))
        voltages = np.empty((N, 3, 1 + nz))
        for j in range(N):
            u[np.arange(3), 1 + 3 * j + np.arange(3)] += 1.0
            if j == 0:
                heading, heading_mid = theta, theta + 0.5 * Ts * w
            else:
                heading, heading_mid = Y_d[j - 1, 2], 0.5 * (Y_d[j - 1, 2] + Y_d[j, 2])
            acc = u - self._damping[:, None] * v
            rate_body = acc.copy()
            rate_body[0] -= w * v[1]
            rate_body[1] += w * v[0]
            W = self.kinematics.matrix(heading)
            omega, omega_rate = W @ v, W @ rate_body
            currents[j] = self._force_to_current * (self._T0 @ _rotation(heading_mid) @ u)
            voltages[j] = self.zoh.voltage(currents[j], i0, omega, omega_rate)
            i0 = ends[j] = self.zoh.end_current(i0, voltages[j], omega, omega_rate)
            v = A_d[:, 1, 1][:, None] * v + B_d[:, 1][:, None] * u
        scaled = np.concatenate(
            (currents / self.nominal_current_a, ends / self.nominal_current_a, voltages / self.supply_voltage_v),
            axis=1,
        ).reshape(self._nrows, 1 + nz)
        return currents, ends, voltages, scaled

    def _qp(self, f: np.ndarray, G: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[bool, np.ndarray]:
        if self._solver is None:
            self._solver = osqp.OSQP()
            self._solver.setup(
                P=sp.csc_matrix(np.triu(self._P)),
                q=f,
                A=sp.csc_matrix(np.ones_like(G)),  # dense pattern, values set below
                l=lower,
                u=upper,
                verbose=False,
                polishing=True,
                eps_abs=1e-12,
                eps_rel=1e-12,
                eps_prim_inf=1e-7,
                max_iter=20000,
            )
            self._solver.update(Ax=G.ravel(order="F"))
        else:
            self._solver.update(q=f, l=lower, u=upper, Ax=G.ravel(order="F"))
        res = self._solver.solve(raise_error=False)
        return res.info.status_val == _SOLVED, res.x

    def solve_increments(
        self,
        X: np.ndarray,
        u_prev: np.ndarray,
        Y_d: np.ndarray,
        i_start: np.ndarray,
        use_closed_form: bool = True,
    ) -> tuple[np.ndarray, bool]:
        """The constrained optimum Delta u(k) .. Delta u(k+N-1).

        Parameters
        ----------
        X
            Measured body state (6,).
        u_prev
            u(k-1) (3,).
        Y_d
            Reference positions (N, 3).
        i_start
            The drive's estimate of the currents at the start of the period (3,).
        use_closed_form
            Return the closed form (56) when it meets every limit (exact, and
            much faster); False always runs the QP solver (checks, benchmarks).

        Returns
        -------
        delta_U : ndarray, shape (N, 3)
        infeasible : bool
            True when the limits could not all hold; delta_U then has the
            least total (scaled) violation and, among those, the least cost.
        """
        *_, rows = self.constraint_rows(X, u_prev, Y_d, i_start)
        h, G = rows[:, 0], rows[:, 1:]
        # A convex QP whose unconstrained minimiser (the closed form 56) is feasible is solved by it.
        if use_closed_form:
            z = self.mpc.solve(X.reshape(3, 2), u_prev, Y_d).ravel()
            if np.max(np.abs(G @ z + h)) <= 1.0:
                return z.reshape(self.N, 3), False
        f = self._linear_cost(X, u_prev, Y_d)
        ok, z = self._qp(f, G, -1.0 - h, 1.0 - h)
        infeasible = False
        if not ok:
            z_lp, slack = self._least_violation(G, h)
            infeasible = bool(slack.max() > _VIOLATION_TOL)
            ok, z = self._qp(f, G, -1.0 - h - slack - 1e-9, 1.0 - h + slack + 1e-9)
            if not ok:  # numerically stuck: the LP's point itself has the least violation
                z = z_lp
        return z.reshape(self.N, 3), infeasible

    @staticmethod
    def _least_violation(G: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A point z and slack s >= 0 of least sum with |G z + h| <= 1 + s (row-wise).

        Should the LP fail (it is always feasible), z = 0 keeps the previous
        input and s is its violation.
        """
        m, nz = G.shape
        eye = np.eye(m)
        A_ub = np.block([[G, -eye], [-G, -eye]])
        b_ub = np.concatenate((1.0 - h, 1.0 + h))
        cost = np.concatenate((np.zeros(nz), np.ones(m)))
        bounds = [(None, None)] * nz + [(0.0, None)] * m
        res = linprog(cost, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
        if res.x is None or not np.all(np.isfinite(res.x)):
            return np.zeros(nz), np.maximum(np.abs(h) - 1.0, 0.0)
        return res.x[:nz], res.x[nz:]

    def solve(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray) -> tuple[np.ndarray, bool]:
        """u(k) = u(k-1) + Delta u(k) of the constrained optimum, and the infeasible flag."""
        delta_U, infeasible = self.solve_increments(X, u_prev, Y_d, i_start)
        return u_prev + delta_U[0], infeasible
