"""Wheel-encoder odometry, as a Robotino measures it: counts, wheel speeds from count differences, dead reckoning.

No rclpy here. The plant integrates each wheel's angle (rim distance / r,
`RobotinoPlant.wheel_angles`); the motor shaft turns `gear_ratio` times as
far and its encoder counts ``floor(gear * angle * counts_per_rev / (2 pi))``
(`encoder_counts`). Each measurement turns the count differences since the
previous one into wheel speeds (`wheel_speeds_from_counts`), those into the
body twist by the forward kinematics of the three omni wheels
(`body_twist`: the inverse of `model.dynamics.wheel_rim_speeds` at heading 0,
i.e. in the robot frame), and integrates the pose with that twist held over
the interval (`integrate_pose`, exact for a constant twist). The pose so
drifts from the truth (quantisation, optional wheel slip) and the controller
tracks in this odom frame while ``ground_truth/odom`` stays the true state.

Wheel slip (``slip_std`` > 0): over each interval the angle the encoder sees
gains, beyond the true one, a Gaussian slip with standard deviation
``slip_std`` times the wheel's true angle change (a fraction of its speed).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, cast

import numpy as np

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.model.dynamics import wheel_directions
from robotino_geom_mpc.params.specs import ParamSpec, RobotinoParams

if TYPE_CHECKING:
    from robotino_geom_mpc.model.plant import RobotinoPlant
    from robotino_geom_mpc.model.plant_batch import PlantBatch

__all__ = [
    "ODOMETRY_MODELS",
    "CONTROLLER_TWIST",
    "DEFAULT_COUNTS_PER_REV",
    "ODOMETRY_SPECS",
    "ODOMETRY_DEFAULTS",
    "EncoderError",
    "encoder_counts",
    "wheel_speeds_from_counts",
    "body_twist",
    "integrate_pose",
    "integrate_poses",
    "twist_covariance",
    "EncoderOdometry",
    "EncoderOdometryBatch",
    "odometry_source",
]

ODOMETRY_MODELS = ("ideal", "encoders")
# the controller's ``control.odometry_twist`` an odometry model's twist asks for (absent: the user's setting):
# the encoders' twist is the mean over the period, which the pose filter's period_mean predictor matches
CONTROLLER_TWIST = {"encoders": "period_mean"}
DEFAULT_COUNTS_PER_REV = 2048  # the public Robotino drivers' motor encoders (gear 16: 32768 counts a wheel turn)

# The plant node's parameters of its odometry (`odometry_source`'s settings).
ODOMETRY_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("odometry_model", str, "ideal: the true pose plus the noise, the true twist; encoders: the pose "
              "integrated from the wheel encoders' counts, the twist from their differences", choices=ODOMETRY_MODELS),
    ParamSpec("encoder.counts_per_rev", int, "Encoder counts per motor revolution", "", 1, 10**6, False),
    ParamSpec("encoder.wheel_slip_std", float, "Wheel slip: std as a fraction of the wheel speed", "", 0.0, 1.0, False),
)
ODOMETRY_DEFAULTS = {"odometry_model": "ideal", "encoder.counts_per_rev": DEFAULT_COUNTS_PER_REV,
                     "encoder.wheel_slip_std": 0.0}

Pose = tuple[float, float, float]


class EncoderError(RobotinoError, ValueError):
    """A bad encoder setting (counts per revolution, slip, odometry model), named in the message."""


def encoder_counts(
    wheel_angles: np.ndarray, gear_ratio: float | np.ndarray, counts_per_rev: int | np.ndarray
) -> np.ndarray:
    """Counts of the motor encoders: floor(gear * wheel angle * counts_per_rev / (2 pi)), as integers."""
    return np.floor(np.asarray(wheel_angles, dtype=float) * (gear_ratio * counts_per_rev / (2.0 * math.pi))).astype(
        np.int64)


def wheel_speeds_from_counts(
    delta_counts: np.ndarray, dt: float, gear_ratio: float | np.ndarray, counts_per_rev: int | np.ndarray
) -> np.ndarray:
    """Mean wheel angular speeds [rad/s] over dt [s] from the count differences of the motor encoders."""
    return np.asarray(delta_counts, dtype=float) * (2.0 * math.pi / (gear_ratio * counts_per_rev * dt))


def body_twist(wheel_speeds: np.ndarray, p: RobotinoParams | np.ndarray) -> np.ndarray:
    """(v_x, v_y, omega) in the robot frame from the wheel speeds [rad/s]: the inverse of `wheel_rim_speeds`.

    The rim speed of wheel i is v_i = d_i(0) . (v_x, v_y) + l omega (`model.dynamics`); the 3x3 matrix K of those
    rows is invertible (the wheels are 120 degrees apart), and the twist is r K^-1 times the wheel speeds. The
    array form: wheel speeds (..., 3) of one robot `p`, or (B, 3) with `p` the B robots' r K^-1 stacked
    (B, 3, 3), give twists of the same shape.
    """
    rows = _twist_of_wheel_speeds(p) if isinstance(p, RobotinoParams) else p
    return np.einsum("...ij,...j->...i", rows, np.asarray(wheel_speeds, dtype=float))


def twist_covariance(p: RobotinoParams, counts_per_rev: int, slip_std: float, period_s: float) -> np.ndarray:
    """A bound of the covariance (3, 3) of the encoders' twist (v_x, v_y, omega in the robot frame), each a mean
    over one period: what ``odom``'s twist covariance reports with ``odometry_model`` encoders.

    Wheel i's speed is its count difference times q / Ts (q = 2 pi / (gear counts_per_rev), a count in wheel
    angle). A difference of two floors is off the true advance by a variance of at most a quarter count
    squared (f (1 - f) for a steady wheel whose advance per period has the fractional part f, 1/6 on average);
    slip adds ``slip_std`` times the wheel speed, taken at the motors' nominal speed. The twist is r K^-1 times
    the wheel speeds (`body_twist`), so with the wheels' errors independent its covariance is
    r^2 K^-1 diag(sigma^2) K^-T.
    """
    quantum = 2.0 * math.pi / (p.gear_ratio * counts_per_rev * period_s)  # one count per period [rad/s]
    nominal = p.nominal_speed_rpm * 2.0 * math.pi / 60.0 / p.gear_ratio  # wheel speed [rad/s]
    variance = 0.25 * quantum**2 + (slip_std * nominal) ** 2
    inverse = _twist_of_wheel_speeds(p)
    return variance * inverse @ inverse.T


def _twist_of_wheel_speeds(p: RobotinoParams) -> np.ndarray:
    """r K^-1 (3, 3): the body twist of the wheel speeds [rad/s], K the rows (d_i(0), l) of `body_twist`."""
    return p.r * np.linalg.inv(np.column_stack((wheel_directions(0.0), np.full(3, p.l))))


def integrate_pose(pose: Pose, twist_body: tuple[float, float, float], dt: float) -> Pose:
    """The pose after dt [s] at the constant body twist (v_x, v_y, omega): the exact SE(2) exponential."""
    x, y, theta = pose
    vx, vy, w = twist_body
    a = w * dt
    if abs(a) < 1e-6:  # series of sin(a)/a and (1 - cos a)/a, error below 1e-19
        s, c = 1.0 - a * a / 6.0, 0.5 * a
    else:
        s, c = math.sin(a) / a, (1.0 - math.cos(a)) / a
    dx, dy = (s * vx - c * vy) * dt, (c * vx + s * vy) * dt  # in the frame at the interval's start
    ct, st = math.cos(theta), math.sin(theta)
    return (x + ct * dx - st * dy, y + st * dx + ct * dy, theta + a)


class EncoderOdometry:
    """Dead reckoning of a `RobotinoPlant` from its motor encoders (see the module docstring).

    Parameters
    ----------
    plant
        The simulated robot (`RobotinoPlant`); its wheel angles and time are read at each measurement.
    counts_per_rev
        Encoder counts per motor revolution.
    slip_std
        Wheel slip: standard deviation as a fraction of each wheel's angle change (0: no slip).
    seed
        Seed of the slip generator.
    pose
        Odometry pose at the start; the plant's pose if None.
    """

    def __init__(self, plant: RobotinoPlant, counts_per_rev: int = DEFAULT_COUNTS_PER_REV, slip_std: float = 0.0,
                 seed: int = 0, pose: Pose | None = None) -> None:
        if isinstance(counts_per_rev, bool) or not isinstance(counts_per_rev, (int, np.integer)) or counts_per_rev < 1:
            raise EncoderError(f"counts_per_rev must be a positive integer, got {counts_per_rev!r}")
        if not (isinstance(slip_std, (int, float)) and 0.0 <= slip_std <= 1.0):
            raise EncoderError(f"slip_std must be a number in [0, 1], got {slip_std!r}")
        self.plant, self.counts_per_rev, self.slip_std = plant, int(counts_per_rev), float(slip_std)
        self._rng = np.random.default_rng((int(seed), 1))  # apart from the pose noise stream default_rng(seed)
        self.pose = cast(Pose, tuple(plant.pose) if pose is None else tuple(float(v) for v in pose))
        self.twist: tuple[float, float, float] = (0.0, 0.0, 0.0)  # no count difference yet
        p = plant.params
        # `update` runs `encoder_counts`, `wheel_speeds_from_counts` and `body_twist` on Python floats (numpy's
        # per-call overhead dominates on 3-vectors): the counts' scale and the inverse kinematics r K^-1 by rows.
        self._count_scale = p.gear_ratio * self.counts_per_rev / (2.0 * math.pi)
        self._gear_counts = p.gear_ratio * self.counts_per_rev
        self._twist_rows = _twist_of_wheel_speeds(p).tolist()
        self._angles = plant.wheel_angles.tolist()  # true wheel angles at the last measurement
        self._seen = list(self._angles)  # the angles the encoders saw (true + slip)
        self._counts = np.array([math.floor(a * self._count_scale) for a in self._seen])  # as `encoder_counts`
        self._time_s = plant.time_s

    def update(self) -> tuple[Pose, tuple[float, float, float]]:
        """Read the encoders, integrate the pose over the time since the last update; (pose, body twist).

        A second update at the same plant time changes nothing.
        """
        dt = self.plant.time_s - self._time_s
        if dt > 0.0:
            # Unrolled over the three wheels: the same operations as the numpy functions, in the same order.
            angles = self.plant.wheel_angles.tolist()
            (a1, a2, a3), (b1, b2, b3), (e1, e2, e3) = angles, self._angles, self._seen
            d1, d2, d3 = a1 - b1, a2 - b2, a3 - b3
            if self.slip_std:
                z1, z2, z3 = self._rng.standard_normal(3).tolist()
                d1, d2, d3 = d1 * (1.0 + self.slip_std * z1), d2 * (1.0 + self.slip_std * z2), \
                    d3 * (1.0 + self.slip_std * z3)
            e1, e2, e3 = e1 + d1, e2 + d2, e3 + d3
            k = self._count_scale
            counts = [math.floor(e1 * k), math.floor(e2 * k), math.floor(e3 * k)]
            (c1, c2, c3), (p1, p2, p3) = counts, self._counts.tolist()
            scale = 2.0 * math.pi / (self._gear_counts * dt)
            s1, s2, s3 = (c1 - p1) * scale, (c2 - p2) * scale, (c3 - p3) * scale
            (r11, r12, r13), (r21, r22, r23), (r31, r32, r33) = self._twist_rows
            self.twist = (r11 * s1 + r12 * s2 + r13 * s3, r21 * s1 + r22 * s2 + r23 * s3,
                          r31 * s1 + r32 * s2 + r33 * s3)
            self.pose = integrate_pose(self.pose, self.twist, dt)
            self._angles, self._seen = angles, [e1, e2, e3]
            self._counts, self._time_s = np.array(counts), self.plant.time_s
        return self.pose, self.twist

    def odometry(
        self, rng: np.random.Generator | None = None, noise_std: tuple[float, float] = (0.0, 0.0)
    ) -> tuple[Pose, tuple[float, float, float]]:
        """As `RobotinoPlant.odometry`, from the encoders: the integrated pose plus the same Gaussian
        pose noise (same draws from the generator) and the encoder-derived body twist.
        """
        return self.noisy_odometry(self.plant.pose_noise(rng, noise_std))

    def noisy_odometry(
        self, noise: tuple[float, float, float] | None
    ) -> tuple[Pose, tuple[float, float, float]]:
        """`odometry` with the pose noise (x, y, theta) given, None: none (noise drawn ahead, unchecked)."""
        pose, twist = self.update()
        if noise is None:
            return pose, twist
        return (pose[0] + noise[0], pose[1] + noise[1], pose[2] + noise[2]), twist


class EncoderOdometryBatch:
    """`EncoderOdometry` of B runs at once, the array form: dead reckoning of a `PlantBatch` from its encoders.

    Parameters
    ----------
    plant
        The batch of simulated robots; each run's wheel angles and the time are read at each measurement.
    counts_per_rev, slip_std
        Per run, shapes (B,) (as for `EncoderOdometry`).
    slip_normals
        The standard normal draws of the slip, shape (updates, B, 3), row k for the k-th update (a run
        without slip: any finite values); None: no run slips.
    runs
        The plant's runs these encoders read (B of them, indices); None: all, in order.

    Notes
    -----
    The same operations as `EncoderOdometry.update`, in the same order, per run: the seen angles gain the
    slip, the counts are their floors, the twist is r K^-1 times the count differences' speeds and the pose
    follows the SE(2) exponential of that twist (`integrate_pose`).
    """

    def __init__(self, plant: PlantBatch, counts_per_rev: np.ndarray, slip_std: np.ndarray,
                 slip_normals: np.ndarray | None = None, runs: np.ndarray | None = None) -> None:
        counts_per_rev = np.asarray(counts_per_rev)
        slip_std = np.asarray(slip_std, dtype=float)
        self._runs: slice | np.ndarray = slice(None) if runs is None else np.asarray(runs)
        params = plant.params if runs is None else [plant.params[int(r)] for r in np.asarray(runs)]
        B = len(params)
        if counts_per_rev.shape != (B,) or np.any(counts_per_rev < 1):
            raise EncoderError(f"counts_per_rev must be {B} positive integers")
        if slip_std.shape != (B,) or not np.all((slip_std >= 0.0) & (slip_std <= 1.0)):
            raise EncoderError(f"slip_std must be {B} numbers in [0, 1]")
        self.plant, self._slip, self._normals, self._updates = plant, slip_std[:, None], slip_normals, 0
        self._twist_rows = np.stack([_twist_of_wheel_speeds(p) for p in params])  # r K^-1 per run
        self._gear = np.array([p.gear_ratio for p in params])[:, None]
        self._counts_per_rev = counts_per_rev[:, None]
        self.pose = plant.pose[self._runs].copy()
        self.twist = np.zeros((B, 3))
        self._angles = plant.wheel_angles[self._runs].copy()
        self._seen = self._angles.copy()
        self._counts = encoder_counts(self._seen, self._gear, self._counts_per_rev)
        self._time_s = plant.time_s

    def update(self) -> tuple[np.ndarray, np.ndarray]:
        """Read the encoders and integrate the poses over the time since the last update; (poses, twists) (B, 3)."""
        dt = self.plant.time_s - self._time_s
        if dt > 0.0:
            angles = self.plant.wheel_angles[self._runs].copy()
            d = angles - self._angles
            if self._normals is not None:
                d = d * (1.0 + self._slip * self._normals[self._updates])
            self._updates += 1
            seen = self._seen + d
            counts = encoder_counts(seen, self._gear, self._counts_per_rev)
            speeds = wheel_speeds_from_counts(counts - self._counts, dt, self._gear, self._counts_per_rev)
            self.twist = body_twist(speeds, self._twist_rows)
            self.pose = integrate_poses(self.pose, self.twist, dt)
            self._angles, self._seen, self._counts, self._time_s = angles, seen, counts, self.plant.time_s
        return self.pose, self.twist


def integrate_poses(pose: np.ndarray, twist: np.ndarray, dt: float) -> np.ndarray:
    """`integrate_pose` of B poses and twists (B, 3) over dt: the array form (`integrate_pose` is the float one)."""
    vx, vy, w = twist.T
    a = w * dt
    small = np.abs(a) < 1e-6  # series of sin(a)/a and (1 - cos a)/a, error below 1e-19
    if small.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(small, 1.0 - a * a / 6.0, np.sin(a) / a)
            c = np.where(small, 0.5 * a, (1.0 - np.cos(a)) / a)
    else:
        s, c = np.sin(a) / a, (1.0 - np.cos(a)) / a
    dx, dy = (s * vx - c * vy) * dt, (c * vx + s * vy) * dt
    ct, st = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    out = np.empty_like(pose)
    np.subtract(pose[:, 0] + ct * dx, st * dy, out=out[:, 0])
    np.add(pose[:, 1] + st * dx, ct * dy, out=out[:, 1])
    np.add(pose[:, 2], a, out=out[:, 2])
    return out


def odometry_source(plant: RobotinoPlant, model: str = "ideal", counts_per_rev: int = DEFAULT_COUNTS_PER_REV,
                    slip_std: float = 0.0, seed: int = 0, pose: Pose | None = None) -> RobotinoPlant | EncoderOdometry:
    """What a measurement of `plant` reads: the plant itself (``ideal``) or an `EncoderOdometry` (``encoders``).

    Either has ``odometry(rng, noise_std) -> (pose, body twist)`` and ``noisy_odometry(noise)``.
    `seed` seeds the slip (a stream of its own: the pose noise keeps the draws of the ideal model).

    Raises
    ------
    EncoderError
        For an unknown model or a bad encoder setting.
    """
    if model == "ideal":
        return plant
    if model == "encoders":
        return EncoderOdometry(plant, counts_per_rev, slip_std, seed, pose)
    raise EncoderError(f"odometry model must be one of {', '.join(ODOMETRY_MODELS)}, got {model!r}")
