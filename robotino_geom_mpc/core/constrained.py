"""Constrained mode (beyond the paper): the MPC cost (54) as a QP with wheel current and voltage limits.

The three axes share the wheels: currents i = (r / (gear Km)) T(theta) u
and voltages U = R i + L_d (i - i_0)/Ts + Km (omega + t_e omega') (see
`drive`) mix u_x, u_y, u_theta, so the limits |i| <= i_nom and |U| <= U_supply
couple the three per-axis problems into one QP over
z = Delta U = (Delta u(k), ..., Delta u(k+N-1)) for all axes (3N variables).

Over the horizon every quantity is affine in z: the inputs (eq. 48), the
velocities of the discrete model (eq. 49), the motor speeds and their rates
(for fixed headings), the currents, the voltages and the drive's predicted
start currents (`drive.ZOHDrive`, whose relations are linear). The heading is
the measured one for the first period (at mid-period, as the controller
applies it) and the reference's for the later ones. Only the headings enter
non-linearly, through planar rotations: so the per-axis signals (u, v and
the body-frame motor-speed rate u - (k/M) v + theta' (-v_y, v_x, 0)) are
fixed matrices times (preview, state, u(k-1), z), rotated by the headings,
and a fixed matrix maps the rotated signals and the start currents to the
constraint rows. A step costs a few small matrix products.

The step first evaluates the unconstrained optimum, the closed form (56),
and checks its rows: a convex QP whose unconstrained minimiser is feasible is
solved by it, so then u(k) is the closed form's, bit for bit. Only when a
limit binds is the QP solved, by DAQP (a dual active-set solver for small
dense QPs: exact on its active set, two-sided rows natively), warm-started
from the previous QP's active set. When the limits cannot all hold, the
least total violation is found by a linear programme (scipy's HiGHS), the
limits are relaxed by exactly that much and the QP solved again: the output
stays finite, the violation is the smallest possible, and the step reports
`infeasible`.
"""

from __future__ import annotations

import daqp
import numpy as np
from scipy.optimize import linprog

from .decoupling import DecouplingField
from .drive import MotorKinematics, ZOHDrive
from .mpc import DecoupledMPC, axis_dampings
from .params import ControlParams, RobotinoParams

__all__ = ["ConstrainedMPC"]

_VIOLATION_TOL = 1e-6  # relative to the limit: larger slack means infeasible
_DAQP_OPTIMAL = 1  # DAQP exitflag of an optimal solution
_max = np.maximum.reduce  # ndarray.max without its Python wrapper
_ONE = np.ones(1)  # the constant entry of the parameter vector
_PRIMAL_TOL = 1e-11  # DAQP primal feasibility tolerance on the scaled rows (its default 1e-6 moves u by ~1e-5)


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
    scaled by their limits, for the wheels w and j = 0..N-1 (row 9 j + 3 kind + w,
    kind 0, 1, 2): the period averages -1 <= i_w(k+j) / i_nom <= 1 (what moves
    the robot), the same for the currents at the period ends (the current
    relaxes exponentially from one end value towards the next, so with the
    averages this bounds it along the whole period up to a hump of about 1 %
    where the back-EMF rises within the period) and -1 <= U_w(k+j) / U_supply <= 1.

    Signals, one 3-vector per column: u(k+j) (rotated by the mid-period
    heading), v(k+j) and the body-frame rate (both rotated by the heading at
    the period's start), columns kind * N + j. With p = (Y_d row by row, X,
    u(k-1), i_0, 1) all of a step's numbers are a few products: the signals
    ``(F0 + theta' F1) p + (Fz0 + theta' Fz1) z`` as rows (s_x, s_y, s_y, -s_x,
    s_theta, i_0), the factors ``cos(A p)`` (cos and sin of the headings, ones),
    and the scaled rows ``B (cos(A p) * signals)``: the rotation of each signal
    into the body frame by R(heading)^T, then the drive relations.
    """

    def __init__(self, robot: RobotinoParams, control: ControlParams, mpc: DecoupledMPC) -> None:
        self.mpc = mpc
        self.N = N = int(control.horizon)
        self.period_s = Ts = float(control.period_s)
        self.nominal_current_a = robot.nominal_current_a
        self.supply_voltage_v = robot.supply_voltage_v
        self._damping = axis_dampings(robot)
        nz, n_p, n_s = 3 * N, 3 * N + 13, 3 * N
        P = np.zeros((nz, nz))
        for a in range(3):
            P[a::3, a::3] = mpc.hessian[a]
        self._scale = 1.0 / float(np.max(np.diag(P)))
        self._P = P * self._scale
        eye_p, eye_z = np.eye(n_p), np.eye(nz)
        # closed form (56) and the QP's linear cost as matrices on p
        K = np.column_stack([self._closed_form(e) for e in eye_p])
        self._cost = -self._P @ K  # the gradient P z + f vanishes at the unconstrained optimum z* = K p
        # signals, linear in (p, z): the recursion of eq. (49) on unit vectors
        S0, C0 = (np.stack(m, axis=-1) for m in zip(*(self._signals(e, np.zeros(nz)) for e in eye_p)))
        Sz, Cz = (np.stack(m, axis=-1) for m in zip(*(self._signals(np.zeros(n_p), e) for e in eye_z)))
        i0 = np.zeros((3, n_p))
        i0[:, 3 * N + 9 : 3 * N + 12] = np.eye(3)
        # signal rows, the part without theta' over its factor's: (F0; F1), (Fz0; Fz1)
        self._F = np.concatenate((self._layout(S0, i0), self._layout(C0, 0 * i0)))
        self._Fz = np.concatenate((self._layout(Sz, np.zeros((3, nz))), self._layout(Cz, np.zeros((3, nz)))))
        # headings: mid-period for u, period start for v and the rate
        H = np.zeros((n_s, n_p))
        H[0, 3 * N + 4], H[0, 3 * N + 5] = 1.0, 0.5 * Ts
        H[N, 3 * N + 4] = H[2 * N, 3 * N + 4] = 1.0
        for j in range(1, N):
            H[j, 3 * (j - 1) + 2] = H[j, 3 * j + 2] = 0.5
            H[N + j, 3 * (j - 1) + 2] = H[2 * N + j, 3 * (j - 1) + 2] = 1.0
        quarter = np.zeros((n_s, n_p))
        quarter[:, -1] = -0.5 * np.pi  # sin(a) = cos(a - pi/2)
        A = np.concatenate((H, H, H + quarter, H + quarter, np.zeros((n_s + 3, n_p))))
        self._A = np.concatenate((A, A))  # factors for both halves; the second is multiplied by theta'
        self._n_sig = 15 * N + 3
        # one product for a step's factors' angles and the signals at the closed form z* = K p
        self._closed_form_map = np.concatenate((self._A, self._F + self._Fz @ K))
        zoh = ZOHDrive(robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a, Ts)
        B = self._rows_matrix(robot, zoh)  # on (rotated x, y, theta components, i_0)
        x, y, t = (np.arange(k * n_s, (k + 1) * n_s) for k in range(3))
        B = B[:, np.concatenate((x, y, x, y, t, np.arange(9 * N, 9 * N + 3)))]
        self._B = np.concatenate((B, B), axis=1)
        self._B_both = np.concatenate((self._B, -self._B))  # max over both signs in one call
        self.reset()

    @staticmethod
    def _layout(S: np.ndarray, i0: np.ndarray) -> np.ndarray:
        """Signal rows (s_x, s_y, s_y, -s_x, s_theta, i_0) from (3, 3N, n) components and (3, n) start currents."""
        return np.concatenate((S[0], S[1], S[1], -S[0], S[2], i0))

    def _closed_form(self, p: np.ndarray) -> np.ndarray:
        """z* of eq. (56) for the parameter vector p."""
        n = 3 * self.N
        return self.mpc.solve(p[n : n + 6].reshape(3, 2), p[n + 6 : n + 9], p[:n].reshape(self.N, 3)).ravel()

    def _signals(self, p: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Un-rotated signals (3, 3N) of (p, z): the part without theta' and the factor of theta'."""
        N, A_d, B_d = self.N, self.mpc.A_d, self.mpc.B_d
        u, v = p[3 * N + 6 : 3 * N + 9].copy(), p[3 * N + 1 : 3 * N + 6 : 2].copy()
        S, C = np.zeros((3, 3 * N)), np.zeros((3, 3 * N))
        for j in range(N):
            u = u + z[3 * j : 3 * j + 3]
            S[:, j], S[:, N + j], S[:, 2 * N + j] = u, v, u - self._damping * v
            C[:2, 2 * N + j] = v[1], -v[0]
            v = A_d[:, 1, 1] * v + B_d[:, 1] * u
        return S, C

    def _rows_matrix(self, robot: RobotinoParams, zoh: ZOHDrive) -> np.ndarray:
        """B, shape (9N, 9N + 3): scaled rows of the rotated signals (x, y, theta components) and i_0."""
        N = self.N
        T0 = DecouplingField(robot).T0 * (robot.r / (robot.gear_ratio * robot.torque_constant_n_m_per_a))
        W0 = MotorKinematics(robot).W0
        n_in = 9 * N + 3
        B = np.zeros((9 * N, n_in))
        for col in range(n_in):
            e = np.eye(n_in)[col]
            sig, i0 = e[: 9 * N].reshape(3, 3 * N), e[9 * N :]
            for j in range(N):
                current = T0 @ sig[:, j]
                omega, rate = W0 @ sig[:, N + j], W0 @ sig[:, 2 * N + j]
                voltage = zoh.voltage(current, i0, omega, rate)
                end = zoh.end_current(i0, voltage, omega, rate)
                B[9 * j : 9 * j + 9, col] = np.concatenate(
                    (current / self.nominal_current_a, end / self.nominal_current_a, voltage / self.supply_voltage_v)
                )
                i0 = end
        return B

    def reset(self) -> None:
        """Drop the warm start (the last active set)."""
        self._daqp: daqp.Model | None = None

    def _parameters(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray) -> np.ndarray:
        """p = (Y_d row by row, X, u(k-1), i_0, 1)."""
        return np.concatenate((Y_d.ravel(), X, u_prev, i_start, _ONE))

    def _factors(self, angles: np.ndarray, w: float) -> np.ndarray:
        """cos of the angles, the second half (theta' terms) times theta'."""
        factors = np.cos(angles)
        factors[self._n_sig :] *= w
        return factors

    def _closed_form_signals(self, p: np.ndarray, w: float) -> tuple[np.ndarray, np.ndarray]:
        """The factors and the factors times the signals at the closed form (56)."""
        both, n = self._closed_form_map @ p, 2 * self._n_sig
        factors = self._factors(both[:n], w)
        return factors, factors * both[n:]

    def closed_form_rows(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray) -> np.ndarray:
        """The scaled constraint rows (9N,) at the closed form (56); feasible iff all lie in [-1, 1]."""
        return self._B @ self._closed_form_signals(self._parameters(X, u_prev, Y_d, i_start), X[5])[1]

    def constraint_rows(
        self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The scaled constraint rows as affine functions h + G z (|h + G z| <= 1 row-wise).

        Parameters
        ----------
        X, u_prev, Y_d, i_start
            As for `solve_increments`.

        Returns
        -------
        h : ndarray, shape (9N,)
        G : ndarray, shape (9N, 3N)
        """
        p = self._parameters(X, u_prev, Y_d, i_start)
        return self._rows(p, self._factors(self._A @ p, X[5]))

    def qp_problem(
        self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The QP min 1/2 z'Pz + f'z subject to |h + G z| <= 1 (row-wise), as (P, f, h, G); P is scaled."""
        p = self._parameters(X, u_prev, Y_d, i_start)
        return (self._P, self._cost @ p, *self._rows(p, self._factors(self._A @ p, X[5])))

    def _rows(self, p: np.ndarray, factors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """h and G for p and the step's factors."""
        return self._B @ (factors * (self._F @ p)), self._B @ (factors[:, None] * self._Fz)

    def _qp(self, f: np.ndarray, G: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[bool, np.ndarray]:
        """DAQP on min 1/2 z'Pz + f'z, lower <= G z <= upper, from the last active set; keeps the new one."""
        data = (np.ascontiguousarray(f), np.ascontiguousarray(G), upper, lower)
        if self._daqp is None:
            self._daqp = daqp.Model()
            self._daqp.setup(self._P, *data, np.zeros(len(upper), dtype=np.int32))
            self._daqp.settings = {"primal_tol": _PRIMAL_TOL}
        else:  # without `sense`, DAQP starts from the active set of its last solve
            self._daqp.update(f=data[0], A=data[1], bupper=upper, blower=lower)
        self._daqp_data = data  # DAQP keeps pointers to the arrays: keep them alive until the next update
        z, _, exitflag, _ = self._daqp.solve()
        ok = exitflag == _DAQP_OPTIMAL
        if not ok:  # start the next QP cold
            self._daqp = None
        return ok, np.asarray(z)

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
        p = self._parameters(X, u_prev, Y_d, i_start)
        factors, signals = self._closed_form_signals(p, X[5])
        if use_closed_form and (self._B_both @ signals).max() <= 1.0:
            return self.mpc.solve(X.reshape(3, 2), u_prev, Y_d), False
        return self._solve_qp(p, factors)

    def _solve_qp(self, p: np.ndarray, factors: np.ndarray) -> tuple[np.ndarray, bool]:
        h, G = self._rows(p, factors)
        f = self._cost @ p
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
        """u(k) = u(k-1) + Delta u(k) of the constrained optimum, and the infeasible flag.

        Where no limit binds, u(k) is the closed-form mode's, bit for bit
        (`DecoupledMPC.delta_u_floats`, the same floating-point operations).
        """
        # the per-tick path: `_closed_form_signals` inlined (each numpy call costs about a microsecond)
        p = np.concatenate((Y_d.ravel(), X, u_prev, i_start, _ONE))
        both, n = self._closed_form_map @ p, 2 * self._n_sig
        factors = np.cos(both[:n])
        factors[self._n_sig :] *= X[5]
        if _max(self._B_both @ (factors * both[n:])) <= 1.0:
            return u_prev + np.array(self.mpc.delta_u_floats(X.tolist(), u_prev.tolist(), Y_d.tolist())), False
        delta_U, infeasible = self._solve_qp(p, factors)
        return u_prev + delta_U[0], infeasible
