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
the body-frame motor-speed rate u - (k/M) v + theta' (v_y, -v_x, 0)) are
fixed matrices times (preview, state, u(k-1), z), rotated by the headings, and
a fixed matrix maps the rotated signals and the start currents to the rows.

The step first evaluates the unconstrained optimum, the closed form (56),
and checks its rows: a convex QP whose unconstrained minimiser is feasible is
solved by it, so then u(k) is the closed form's, bit for bit. The check (five
numpy calls on fixed buffers) runs only when a screen (`limit_screen`) cannot
decide: a bound, in a few float operations, of the rows' change since the
last checked tick. Only when a limit binds is the QP solved, shifted to the
closed form (z = z* + d: no linear cost, bounds 1 -/+ the rows at z*), by
DAQP (a dual active-set solver for small dense QPs: exact on its active set,
two-sided rows natively; `warm_qp`, set up once), warm-started from the
previous QP's active set; its G is the step's 6N + 1 distinct factors times
one fixed matrix. When the limits cannot all hold, the least total violation
is found by a linear programme (scipy's HiGHS), the limits are relaxed by
exactly that much and the QP solved again: the output stays finite, the violation is the smallest
possible, and the step reports `infeasible`.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import chain

import numpy as np

from robotino_geom_mpc.geometric.decoupling import DecouplingField
from robotino_geom_mpc.control.inverse_drive import ZOHDrive
from robotino_geom_mpc.model.kinematics import MotorKinematics
from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.control.limit_screen import LimitScreen
from robotino_geom_mpc.control.mpc import DecoupledMPC, axis_dampings
from robotino_geom_mpc.params.specs import ControlParams, RobotinoParams

__all__ = ["ConstrainedMPC", "ConstrainedModeError"]


class ConstrainedModeError(RobotinoError, RuntimeError):
    """The constrained mode cannot run here: its QP solver (the daqp package) is not installed."""

_VIOLATION_TOL = 1e-6  # relative to the limit: larger slack means infeasible
_min = np.minimum.reduce  # ndarray.min without its Python wrapper
_ONE = np.ones(1)  # the constant entry of the parameter vector


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
    into the body frame by R(heading)^T, then the drive relations. Only the
    4N rate rows of s_x, s_y carry theta': they come last, and the theta'
    parts extend the signals (factors theta' times theirs, columns of B repeated).
    """

    def __init__(self, robot: RobotinoParams, control: ControlParams, mpc: DecoupledMPC) -> None:
        from scipy.optimize import linprog  # here: 0.65 s of import the closed-form nodes need not pay
        try:  # here too: daqp (pip only, no rosdep key) is needed by the constrained mode alone
            from robotino_geom_mpc.control.warm_qp import WarmDaqp
        except ImportError as exc:
            raise ConstrainedModeError(
                f"control.mode constrained needs the daqp package (pip install 'daqp>=0.11,<1'): {exc}") from None
        self._linprog = linprog
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
        # signals, linear in (p, z): the recursion of eq. (49) on unit vectors
        S0, C0 = (np.stack(m, axis=-1) for m in zip(*(self._signals(e, np.zeros(nz)) for e in eye_p)))
        Sz, Cz = (np.stack(m, axis=-1) for m in zip(*(self._signals(np.zeros(n_p), e) for e in eye_z)))
        i0 = np.zeros((3, n_p))
        i0[:, 3 * N + 9 : 3 * N + 12] = np.eye(3)
        # signal rows, the part without theta' over its factor's: (F0; F1), (Fz0; Fz1)
        F = np.concatenate((self._layout(S0, i0), self._layout(C0, 0 * i0)))
        Fz = np.concatenate((self._layout(Sz, np.zeros((3, nz))), self._layout(Cz, np.zeros((3, nz)))))
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
        zoh = ZOHDrive(robot.resistance_ohm, robot.inductance_h, robot.torque_constant_n_m_per_a, Ts)
        B = self._rows_matrix(robot, zoh)  # on (rotated x, y, theta components, i_0)
        x, y, t = (np.arange(k * n_s, (k + 1) * n_s) for k in range(3))
        B = B[:, np.concatenate((x, y, x, y, t, np.arange(9 * N, 9 * N + 3)))]
        # theta' enters only the x, y rows of the rate (blocks s_x, s_y, s_y, -s_x): put them last, and
        # extend the signals by their theta' parts, whose factors are theta' times the rate rows' factors
        n_sig = 15 * N + 3
        rate = np.concatenate([np.arange(b * n_s + 2 * N, (b + 1) * n_s) for b in range(4)])
        order = np.concatenate((np.setdiff1d(np.arange(n_sig), rate), rate))
        self._n_sig, self._n_rate = n_sig, len(rate)
        F_ext = np.concatenate((F[:n_sig][order], F[n_sig:][rate]))  # (n_sig + 4N, n_p)
        Fz_ext = np.concatenate((Fz[:n_sig][order], Fz[n_sig:][rate]))
        B = B[:, order]
        B_ext = np.concatenate((B, B[:, n_sig - self._n_rate :]), axis=1)
        A = A[order]  # the angles of the factors
        # one product for the factors' angles, the extended signals at the closed form z* = K p, and z*
        self._closed_form_map = np.concatenate((A, F_ext + Fz_ext @ K, K))
        # the rows' margins 1 - rows and 1 + rows (all >= 0: the limits hold) in one product, the constant last
        ones = np.ones((len(B_ext), 1))
        self._B_margins = np.block([[-B_ext, ones], [B_ext, ones]])
        self._screen = LimitScreen(mpc, A, F_ext + Fz_ext @ K, B_ext, n_sig, self._n_rate)
        # G = B_ext diag(factors) Fz_ext = sum over the distinct factors (4N + 1 cos, 2N theta' cos) of
        # the factor times a fixed matrix: rows of equal angle (and theta' or not) share a factor
        theta = np.arange(len(F_ext)) >= n_sig
        keys = np.column_stack((np.concatenate((A, A[n_sig - self._n_rate :])), theta))
        _, self._distinct, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        self._G_map = np.zeros((len(self._distinct), B_ext.size // len(F_ext) * nz))
        np.add.at(self._G_map, group.ravel(), np.einsum("rk,kz->krz", B_ext, Fz_ext).reshape(len(F_ext), -1))
        self._buffers(n_p, nz, len(F_ext))
        self._daqp = WarmDaqp(self._P, 9 * N)
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

    def _buffers(self, n_p: int, nz: int, n_ext: int) -> None:
        """Arrays every step writes into (no per-tick allocation); views of them named once."""
        m, n_sig = 9 * self.N, self._n_sig
        self._p = np.empty(n_p)
        self._map_out = np.empty(len(self._closed_form_map))
        self._angles, self._signals_z = self._map_out[:n_sig], self._map_out[n_sig : n_sig + n_ext]
        self._z_star = self._map_out[n_sig + n_ext :]
        self._ext_factors, self._ext_product_one = np.empty(n_ext), np.ones(n_ext + 1)
        self._ext_product = self._ext_product_one[:n_ext]  # its last entry stays 1: the margins' constant
        self._factors = self._ext_factors[:n_sig]  # cos of the angles
        self._rate_factors = self._ext_factors[n_sig - self._n_rate : n_sig]
        self._theta_factors = self._ext_factors[n_sig:]  # theta' times the rate rows' factors
        self._distinct_factors, self._G_flat = np.empty(len(self._distinct)), np.zeros(m * nz)
        self._G = self._G_flat.reshape(m, nz)
        self._margins = np.empty(2 * m)  # 1 - rows, 1 + rows (rows at z*)
        self._upper, self._plus = self._margins[:m], self._margins[m:]
        self._lower = np.empty(m)  # the QP's bounds: upper 1 - rows, lower -1 - rows

    def reset(self) -> None:
        """Drop the warm start (the last active set) and the screen's reference."""
        self._daqp.reset()
        self._screen.reset()

    def _closed_form_check(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray) -> bool:
        """Whether the closed form (56) meets every limit; leaves p and the step's factors in the buffers."""
        np.concatenate((Y_d.ravel(), X, u_prev, i_start, _ONE), out=self._p)
        return self._check(X[5])

    def _check(self, w: float) -> bool:
        """`_closed_form_check` for the p in its buffer and theta' = w.

        Five calls on fixed buffers: the factors' angles and the extended
        signals at z* = K p in one product; the cos of the angles; theta' times
        the rate rows' factors; their products with the signals; the rows'
        margins 1 - rows and 1 + rows; then whether the least is >= 0.
        """
        np.dot(self._closed_form_map, self._p, self._map_out)
        np.cos(self._angles, out=self._factors)
        np.multiply(self._rate_factors, w, out=self._theta_factors)
        np.multiply(self._ext_factors, self._signals_z, out=self._ext_product)
        np.dot(self._B_margins, self._ext_product_one, self._margins)
        return bool(_min(self._margins) >= 0.0)

    def _rows(self) -> np.ndarray:
        """The scaled rows at z* of the last check (from its margins)."""
        return 1.0 - self._upper

    def _rows_max(self) -> float:
        """max |rows| at z* of the last check."""
        return 1.0 - float(_min(self._margins))

    def _constraint_matrix(self) -> None:
        """G for the factors in the buffers (`_closed_form_check` first): the distinct factors times one matrix."""
        self._ext_factors.take(self._distinct, out=self._distinct_factors)
        np.dot(self._distinct_factors, self._G_map, self._G_flat)

    def closed_form_rows(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray) -> np.ndarray:
        """The scaled constraint rows (9N,) at the closed form (56); feasible iff all lie in [-1, 1]."""
        self._closed_form_check(X, u_prev, Y_d, i_start)
        return self._rows()

    def constraint_rows(
        self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The scaled constraint rows as affine functions h + G z (|h + G z| <= 1 row-wise), h (9N,), G (9N, 3N).

        The arguments are those of `solve_increments`.
        """
        return self.qp_problem(X, u_prev, Y_d, i_start)[2:]

    def qp_problem(
        self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The QP min 1/2 z'Pz + f'z subject to |h + G z| <= 1 (row-wise), as (P, f, h, G); P is scaled."""
        self._closed_form_check(X, u_prev, Y_d, i_start)
        self._constraint_matrix()
        G, z = self._G.copy(), self._z_star
        return self._P, -(self._P @ z), self._rows() - G @ z, G

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
        if self._closed_form_check(X, u_prev, Y_d, i_start) and use_closed_form:
            return self.mpc.solve(X.reshape(3, 2), u_prev, Y_d), False
        d, infeasible = self._solve_qp()
        return (self._z_star + d).reshape(self.N, 3), infeasible

    def _solve_qp(self) -> tuple[np.ndarray, bool]:
        """d of the QP for the p and factors in the buffers (`_closed_form_check` first): Delta U = z* + d.

        With z = z* + d the cost (54) is 1/2 d'Pd plus a constant (its gradient
        vanishes at z*) and the rows are r* + G d, r* those at z*: the QP has
        no linear cost, and its bounds are +-1 - r* (the check's margins).
        """
        self._constraint_matrix()
        G = self._G
        np.negative(self._plus, out=self._lower)
        ok, d = self._daqp.solve(G, self._lower, self._upper)
        infeasible = False
        if not ok:
            d_lp, slack = self._least_violation(G, self._rows())
            infeasible = bool(slack.max() > _VIOLATION_TOL)
            ok, d = self._daqp.solve(G, self._lower - slack - 1e-9, self._upper + slack + 1e-9)
            if not ok:  # numerically stuck: the LP's point itself has the least violation
                d = d_lp
        return d, infeasible

    def _least_violation(self, G: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
        res = self._linprog(cost, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
        if res.x is None or not np.all(np.isfinite(res.x)):
            return np.zeros(nz), np.maximum(np.abs(h) - 1.0, 0.0)
        return res.x[:nz], res.x[nz:]

    def solve(self, X: np.ndarray, u_prev: np.ndarray, Y_d: np.ndarray, i_start: np.ndarray) -> tuple[np.ndarray, bool]:
        """u(k) = u(k-1) + Delta u(k) of the constrained optimum, and the infeasible flag.

        Where no limit binds, u(k) is the closed-form mode's, bit for bit
        (`DecoupledMPC.delta_u`, the same floating-point operations).
        Not re-entrant: the step works in the instance's buffers.
        """
        if self._closed_form_check(X, u_prev, Y_d, i_start):
            return u_prev + np.array(self.mpc.delta_u(X.tolist(), u_prev.tolist(), Y_d.tolist())), False
        d, infeasible = self._solve_qp()
        return u_prev + (self._z_star[:3] + d[:3]), infeasible

    def solve_floats(
        self, X: Sequence[float], u_prev: Sequence[float], Y_d: Sequence[Sequence[float]], i_start: Sequence[float]
    ) -> tuple[list[float], bool]:
        """`solve` on Python floats (the controller's per-tick path): u(k) as 3 floats, and the infeasible flag.

        The same numbers as `solve`, bit for bit: the full check (p filled from the floats) runs only
        when the screen (`limit_screen.LimitScreen`, a few float operations) cannot prove the limits.
        A tick where a limit binds drops the screen's reference (the next tick is checked in full).
        """
        if not self._screen.passes(X, u_prev, Y_d, i_start):
            self._p[:] = [*chain.from_iterable(Y_d), *X, *u_prev, *i_start, 1.0]
            if not self._check(X[5]):
                self._screen.reset()
                d, infeasible = self._solve_qp()
                du_x, du_y, du_theta = (self._z_star[:3] + d[:3]).tolist()
                return [u_prev[0] + du_x, u_prev[1] + du_y, u_prev[2] + du_theta], infeasible
            self._screen.set_reference(X, u_prev, i_start, self._p, self._signals_z, self._rows_max())
        du_x, du_y, du_theta = self.mpc.delta_u(X, u_prev, Y_d)
        return [u_prev[0] + du_x, u_prev[1] + du_y, u_prev[2] + du_theta], False
