"""The Robotino model of Section II: body dynamics (eqs. 1-9), DC drives (eq. 10), and their coupling.

State of the body (eq. 2): X = (x, x', y, y', theta, theta'), outputs
(x, y, theta) (eq. 5). The coupled plant adds the three armature currents:
(X, i_1, i_2, i_3).

Conventions and corrections (docs/theory.md, "Errata of the paper"):

* wheel i pushes along d_i(theta) = (sin(phi_i - theta), cos(phi_i - theta))
  = R(theta) d_i(0) in the odom frame, phi = (0, 2 pi/3, -2 pi/3): the
  wheel directions turn with the robot in REP-103 frames (x forward, y left,
  yaw counter-clockwise), where rows 2 and 4 of eq. (9) print phi_i + theta,
  directions turning against the yaw (erratum 6). In base_link wheel i sits
  at l (cos beta_i, sin beta_i), beta_i = -phi_i, and rolls along
  d_i(0) = (-sin beta_i, cos beta_i), the counter-clockwise tangent;
* every wheel gives torque l F_i, so the angular row of g(theta) is
  (l/J, l/J, l/J) (erratum 1); the 3x3 acceleration block then has a
  constant determinant and there is no singularity at pi/2 + k pi (erratum 2);
* wheel force F_i = gear Km i_i / r (erratum 4; gear = 1 gives the paper's);
* the back-EMF of motor i is Km omega_i with omega_i = gear v_i / r and
  v_i = d_i(theta) . (x', y') + l theta' the rim speed of wheel i, the
  no-slip kinematics dual to g(theta) (the power F . v balances).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.arrays import checked_array
from robotino_geom_mpc.params.specs import RobotinoParams

__all__ = [
    "WHEEL_ANGLES_RAD",
    "N_BODY",
    "N_PLANT",
    "OUTPUT_INDEX",
    "VELOCITY_INDEX",
    "ModelError",
    "A_matrix",
    "C_matrix",
    "C_x",
    "C_y",
    "C_theta",
    "wheel_directions",
    "wheel_rolling_directions",
    "wheel_positions",
    "g_theta",
    "acceleration_block",
    "acceleration_blocks",
    "force_per_current",
    "wheel_rim_speeds",
    "motor_speeds",
    "wheel_forces",
    "currents_from_forces",
    "drive_matrices",
    "coupled_rhs",
]

WHEEL_ANGLES_RAD = np.array([0.0, 2.0 * np.pi / 3.0, -2.0 * np.pi / 3.0])
N_BODY = 6
N_PLANT = 9
OUTPUT_INDEX = np.array([0, 2, 4])  # x, y, theta in X
VELOCITY_INDEX = np.array([1, 3, 5])  # x', y', theta' in X


class ModelError(RobotinoError, ValueError):
    """An input of the model with the wrong shape or non-finite values."""


def _vector(value: object, size: int, name: str) -> np.ndarray:
    return checked_array(value, (size,), name, ModelError, finite=False)


def A_matrix(p: RobotinoParams) -> np.ndarray:
    """State matrix A of the body, eq. (3): three decoupled blocks (x, y, theta)."""
    A = np.zeros((6, 6))
    for k, damping in enumerate((p.k_x / p.M, p.k_y / p.M, p.k_theta / p.J)):
        A[2 * k, 2 * k + 1] = 1.0
        A[2 * k + 1, 2 * k + 1] = -damping
    return A


def C_matrix() -> np.ndarray:
    """Output matrix C, eq. (5): positions x, y, theta."""
    C = np.zeros((3, 6))
    C[np.arange(3), OUTPUT_INDEX] = 1.0
    return C


def C_x() -> np.ndarray:
    """Row C_x, eq. (6)."""
    return C_matrix()[0:1]


def C_y() -> np.ndarray:
    """Row C_y, eq. (7)."""
    return C_matrix()[1:2]


def C_theta() -> np.ndarray:
    """Row C_theta, eq. (8)."""
    return C_matrix()[2:3]


def wheel_directions(theta: float) -> np.ndarray:
    """Drive directions d_i(theta) = R(theta) d_i(0) of the three wheels in the odom frame, shape (3, 2).

    Rows 2 and 4 of eq. (9) with the heading's sign corrected (erratum 6):
    d_i(theta) = (sin(phi_i - theta), cos(phi_i - theta)).
    """
    angles = WHEEL_ANGLES_RAD - theta
    return np.column_stack((np.sin(angles), np.cos(angles)))


def wheel_rolling_directions() -> np.ndarray:
    """Rolling directions d_i(0) of the wheels in base_link (unit vectors), shape (3, 2).

    The counter-clockwise tangent at each wheel's position (`wheel_positions`),
    so a positive wheel force gives the torque +l F_i.
    """
    return wheel_directions(0.0)


def wheel_positions(p: RobotinoParams) -> np.ndarray:
    """Contact points of the wheels in base_link [m], shape (3, 2): l (cos beta_i, sin beta_i), beta_i = -phi_i."""
    beta = -WHEEL_ANGLES_RAD
    return p.l * np.column_stack((np.cos(beta), np.sin(beta)))


def acceleration_block(theta: float, p: RobotinoParams) -> np.ndarray:
    """Rows 2, 4, 6 of g(theta): (x'', y'', theta'') per unit wheel force, shape (3, 3)."""
    return acceleration_blocks(np.array([theta]), np.array([p.M]), np.array([p.l / p.J]))[0]


def acceleration_blocks(theta: NDArray[np.float64], mass: NDArray[np.float64],
                        lever_per_inertia: NDArray[np.float64]) -> NDArray[np.float64]:
    """`acceleration_block` of B runs at once, shape (B, 3, 3): rows d_i(theta) / M (`wheel_directions`) and l / J.

    Parameters
    ----------
    theta
        The headings (B,) [rad].
    mass, lever_per_inertia
        Each run's M [kg] and l / J [1/(kg m)], shape (B,).
    """
    angles = WHEEL_ANGLES_RAD - theta[:, None]
    per_mass = mass[:, None]
    return np.stack((np.sin(angles) / per_mass, np.cos(angles) / per_mass,
                     np.broadcast_to(lever_per_inertia[:, None], angles.shape)), axis=1)


def g_theta(theta: float, p: RobotinoParams) -> np.ndarray:
    """Input field g(theta) of eq. (9) with the consistent angular row (erratum 1), shape (6, 3)."""
    g = np.zeros((6, 3))
    g[VELOCITY_INDEX] = acceleration_block(theta, p)
    return g


def wheel_rim_speeds(theta: float, velocity: np.ndarray, p: RobotinoParams) -> np.ndarray:
    """Rim speeds v_i = d_i(theta) . (x', y') + l theta' of the wheels [m/s].

    Parameters
    ----------
    velocity
        (x', y', theta') in the odom frame.
    """
    v = _vector(velocity, 3, "velocity")
    return wheel_directions(theta) @ v[:2] + p.l * v[2]


def motor_speeds(theta: float, velocity: np.ndarray, p: RobotinoParams) -> np.ndarray:
    """Motor shaft speeds omega_i = gear v_i / r [rad/s]."""
    return p.gear_ratio / p.r * wheel_rim_speeds(theta, velocity, p)


def wheel_forces(currents: np.typing.ArrayLike, p: RobotinoParams) -> np.ndarray:
    """Wheel forces F = gear Km i / r [N] (text after eq. 9, erratum 4)."""
    return force_per_current(p) * _vector(currents, 3, "currents")


def force_per_current(p: RobotinoParams) -> float:
    """gear Km / r [N/A]: a wheel's force per unit motor current (text after eq. 9, erratum 4)."""
    return p.gear_ratio * p.torque_constant_n_m_per_a / p.r


def currents_from_forces(forces: np.ndarray, p: RobotinoParams) -> np.ndarray:
    """Inverse of `wheel_forces`: i = F r / (gear Km) [A]."""
    return p.r / (p.gear_ratio * p.torque_constant_n_m_per_a) * _vector(forces, 3, "forces")


def drive_matrices(p: RobotinoParams) -> tuple[np.ndarray, np.ndarray]:
    """The three free DC drives of eq. (10): state (i_1, w_1, i_2, w_2, i_3, w_3), input U.

    J is the rotor inertia and K the motor viscous friction. Used for the
    drive's own functional-controllability order; in the coupled plant the
    rotor speeds are tied to the body by the wheel kinematics instead.
    """
    R, L, Km = p.resistance_ohm, p.inductance_h, p.torque_constant_n_m_per_a
    Jm, K = p.rotor_inertia_kg_m2, p.viscous_friction_n_m_s
    if Jm <= 0.0:
        raise ModelError("drive_matrices needs a positive rotor inertia")
    block = np.array([[-R / L, -Km / L], [Km / Jm, -K / Jm]])
    A = np.kron(np.eye(3), block)
    B = np.kron(np.eye(3), np.array([[1.0 / L], [0.0]]))
    return A, B


def coupled_rhs(state: np.ndarray, voltages: np.ndarray, p: RobotinoParams) -> np.ndarray:
    """Time derivative of the coupled plant (body + three drives).

    X' = A X + g(theta) F with F = gear Km i / r, and
    L i' = U - R i - Km omega_motor(theta, X').

    Parameters
    ----------
    state
        (x, x', y, y', theta, theta', i_1, i_2, i_3).
    voltages
        Armature voltages U_1..3 [V].
    """
    s = _vector(state, N_PLANT, "state")
    U = _vector(voltages, 3, "voltages")
    X, i = s[:N_BODY], s[N_BODY:]
    theta = X[4]
    Xdot = A_matrix(p) @ X + g_theta(theta, p) @ wheel_forces(i, p)
    omega = motor_speeds(theta, X[VELOCITY_INDEX], p)
    idot = (U - p.resistance_ohm * i - p.torque_constant_n_m_per_a * omega) / p.inductance_h
    return np.concatenate((Xdot, idot))
