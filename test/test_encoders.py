"""Encoder odometry (robotino_geom_mpc.model.encoders) against analytical truths and the plant's own wheel angles."""

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from robotino_geom_mpc.model.dynamics import wheel_rim_speeds
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.model.encoders import (
    EncoderError,
    EncoderOdometry,
    body_twist,
    integrate_pose,
    odometry_source,
    twist_covariance,
)
from robotino_geom_mpc.model.plant import RobotinoPlant

ROBOT, CONTROL = load_params()
TS = CONTROL.period_s
CPR = 2048
PHI = (0.0, 2.0 * math.pi / 3.0, -2.0 * math.pi / 3.0)  # the wheels' mounting angles (model.dynamics conventions)


class ConstantWheels:
    """A stand-in plant whose wheels turn at constant speeds [rad/s] from pose (0, 0, 0): angles = speed * t."""

    def __init__(self, speeds):
        self.params, self.speeds, self.time_s = ROBOT, np.asarray(speeds, float), 0.0
        self.pose = np.zeros(3)
        self._plant = RobotinoPlant(ROBOT)  # for pose_noise only

    @property
    def wheel_angles(self):
        return self.speeds * self.time_s

    def pose_noise(self, rng, noise_std):
        return self._plant.pose_noise(rng, noise_std)


def _run(speeds, periods, cpr=CPR):
    wheels = ConstantWheels(speeds)
    odometry = EncoderOdometry(wheels, cpr)
    counts = []
    for k in range(1, periods + 1):
        wheels.time_s = k * TS
        pose, twist = odometry.update()
        counts.append(odometry._counts.tolist())
    return wheels, pose, twist, counts


@pytest.mark.unit
def test_counts_are_the_floor_of_the_motor_angle_in_counts():
    speeds = [3.7, -1.3, 0.05]  # wheel rad/s
    _, _, _, counts = _run(speeds, 50)
    for k, row in enumerate(counts, start=1):
        # motor angle = gear * wheel angle; one revolution = CPR counts
        expected = [math.floor(ROBOT.gear_ratio * w * k * TS * CPR / (2.0 * math.pi)) for w in speeds]
        assert row == expected


def _count_step():
    """Wheel angle of one count [rad]."""
    return 2.0 * math.pi / (ROBOT.gear_ratio * CPR)


@pytest.mark.unit
def test_straight_line_integrates_to_the_analytical_pose():
    v, T = 0.3, 2.0  # m/s along the robot's x axis, heading 0
    rim = [v * math.sin(phi) for phi in PHI]  # v_i = d_i(0) . (v, 0) with d_i = (sin phi_i, cos phi_i)
    _, pose, twist, _ = _run([s / ROBOT.r for s in rim], round(T / TS))
    q = _count_step()
    theta_bound = ROBOT.r * q / ROBOT.l  # one count per wheel in sum(angles) r / (3 l)
    assert abs(pose[2]) <= theta_bound
    assert abs(pose[0] - v * T) <= 2.0 * ROBOT.r * q + v * T * theta_bound
    assert abs(pose[1]) <= 2.0 * ROBOT.r * q + v * T * theta_bound
    assert twist[0] == pytest.approx(v, abs=2.0 * ROBOT.r * q / TS)


@pytest.mark.unit
def test_pure_rotation_integrates_to_the_analytical_heading():
    w, T = 1.5, 3.0  # rad/s
    speeds = [ROBOT.l * w / ROBOT.r] * 3  # v_i = l theta'
    _, pose, twist, _ = _run(speeds, round(T / TS))
    q = _count_step()
    assert abs(pose[2] - w * T) <= ROBOT.r * q / ROBOT.l
    assert math.hypot(pose[0], pose[1]) <= 2.0 * ROBOT.r * q
    assert twist[2] == pytest.approx(w, abs=ROBOT.r * q / (ROBOT.l * TS))
    assert pose[2] != w * T  # quantised, not the exact value


@pytest.mark.unit
def test_wheel_speeds_are_within_one_count_per_period_of_the_plant():
    plant = RobotinoPlant(ROBOT)
    odometry = EncoderOdometry(plant, CPR)
    rng = np.random.default_rng(3)
    bound = _count_step() / TS
    errors = []
    for _ in range(300):
        before = plant.wheel_angles
        plant.step(rng.uniform(-12.0, 12.0, 3), TS)
        true_mean = (plant.wheel_angles - before) / TS
        _, twist = odometry.update()
        measured = wheel_rim_speeds(0.0, np.array(twist), ROBOT) / ROBOT.r  # back to wheel speeds
        errors.append(measured - true_mean)
    errors = np.abs(errors)
    assert errors.max() < bound
    assert errors.max() > 0.5 * bound  # quantisation is there, not zero
    # theta' = r sum(wheel speeds) / (3 l), so the heading is the summed counts: within one count per wheel
    # of the truth whatever the motion; the position drifts (quantisation, twist held over each period), but
    # only slightly: the body-frame kinematics and the plant agree on the handedness (REP-103, erratum 6; with
    # the printed g(theta) the wheel directions turned against the yaw and the drift here was 1.7e-2 m)
    assert abs(odometry.pose[2] - plant.pose[2]) <= ROBOT.r * _count_step() / ROBOT.l
    assert 0.0 < np.hypot(*(np.array(odometry.pose[:2]) - plant.pose[:2])) < 2e-5


@pytest.mark.unit
def test_body_twist_inverts_the_rim_speeds():
    rng = np.random.default_rng(0)
    for twist in rng.normal(size=(20, 3)):
        speeds = wheel_rim_speeds(0.0, twist, ROBOT) / ROBOT.r
        assert np.allclose(body_twist(speeds, ROBOT), twist, atol=1e-12)


@pytest.mark.unit
@pytest.mark.parametrize("twist", [(0.4, -0.2, 2.0), (0.3, 0.1, 0.0), (0.0, 0.0, -1.0)])
def test_integrate_pose_matches_a_numerical_integration(twist):
    start, dt = (0.5, -0.2, 0.7), 0.3
    vx, vy, w = twist

    def rhs(_, s):
        c, si = math.cos(s[2]), math.sin(s[2])
        return [c * vx - si * vy, si * vx + c * vy, w]

    ref = solve_ivp(rhs, (0.0, dt), start, rtol=1e-12, atol=1e-14).y[:, -1]
    assert np.allclose(integrate_pose(start, twist, dt), ref, atol=1e-11)


@pytest.mark.unit
def test_slip_scatters_the_measured_wheel_speeds_by_the_fraction():
    wheels = ConstantWheels([10.0, -10.0, 5.0])
    odometry = EncoderOdometry(wheels, 2**30, slip_std=0.05, seed=4)  # quantisation negligible
    ratios = []
    for k in range(1, 801):
        wheels.time_s = k * TS
        _, twist = odometry.update()
        ratios.append(wheel_rim_speeds(0.0, np.array(twist), ROBOT) / ROBOT.r / wheels.speeds)
    scatter = np.std(np.array(ratios) - 1.0, axis=0)
    assert np.all(np.abs(scatter - 0.05) < 0.01)


def _twist_errors(speeds: np.ndarray, slip_std: float, seed: int, periods: int = 400) -> np.ndarray:
    """Encoder twist minus the true (constant) twist of wheels turning at `speeds`, per period."""
    wheels = ConstantWheels(speeds)
    wheels.time_s = np.random.default_rng(seed).uniform(0.0, 1.0)  # a random phase of the counts
    odometry = EncoderOdometry(wheels, CPR, slip_std=slip_std, seed=seed)
    start, errors = wheels.time_s, []
    true = np.linalg.solve(np.column_stack((np.sin(PHI), np.cos(PHI), np.full(3, ROBOT.l))), ROBOT.r * wheels.speeds)
    for k in range(1, periods + 1):
        wheels.time_s = start + k * TS
        errors.append(np.array(odometry.update()[1]) - true)
    return np.array(errors)


@pytest.mark.slow
@pytest.mark.unit
@pytest.mark.parametrize("advance, ratio", [("random", 2.0 / 3.0), ("half a count", 1.0)])
def test_twist_covariance_bounds_the_quantisation_and_is_reached_at_half_a_count(advance, ratio):
    """A steady wheel's count difference is off by f (1 - f) counts squared in variance (f: the fractional part
    of its advance per period): 1/6 on average over f, 1/4 at f = 1/2, which the bound takes for every wheel
    (the wheels' errors independent: over phases, on average).
    """
    bound = np.diag(twist_covariance(ROBOT, CPR, 0.0, TS))
    count_speed = 2.0 * math.pi / (ROBOT.gear_ratio * CPR * TS)  # one count per period [rad/s]
    rng = np.random.default_rng(7)
    errors = []
    for seed in range(2000):  # many speeds and phases: within one, f and the wheels' error signs stay
        if advance == "random":
            speeds = rng.uniform(-300.0, 300.0, 3) * count_speed
        else:
            speeds = (rng.integers(-300, 300, 3) + 0.5) * count_speed
        errors.append(_twist_errors(speeds, 0.0, seed, 10))
    variance = np.concatenate(errors).var(axis=0)
    assert np.all(np.abs(variance / bound - ratio) < 0.1 * ratio), variance / bound


@pytest.mark.unit
def test_twist_covariance_takes_the_slip_at_the_nominal_speed():
    """Wheels at the motors' nominal speed advance a whole number of counts a period here (no quantisation
    error to speak of), so the scatter is the slip's: slip_std times the nominal wheel speed.
    """
    nominal = ROBOT.nominal_speed_rpm * 2.0 * math.pi / 60.0 / ROBOT.gear_ratio
    speeds = np.array([1.0, -1.0, 1.0]) * nominal
    errors = np.concatenate([_twist_errors(speeds, 0.02, seed, 800) for seed in range(5)])
    bound = np.diag(twist_covariance(ROBOT, CPR, 0.02, TS))
    slip_only = bound - np.diag(twist_covariance(ROBOT, CPR, 0.0, TS))
    assert np.all(np.abs(errors.var(axis=0) / slip_only - 1.0) < 0.1), errors.var(axis=0) / slip_only


@pytest.mark.unit
def test_pose_noise_is_the_ideal_models_draws():
    plant = RobotinoPlant(ROBOT)
    plant.step(np.array([5.0, -3.0, 1.0]), TS)
    encoders = EncoderOdometry(RobotinoPlant(ROBOT), CPR)
    clean, _ = encoders.odometry()
    noisy, _ = encoders.odometry(np.random.default_rng(9), (0.01, 0.02))
    ideal, _ = plant.odometry(np.random.default_rng(9), (0.01, 0.02))
    assert np.allclose(np.subtract(noisy, clean), np.subtract(ideal, plant.pose), atol=1e-15)


@pytest.mark.unit
def test_a_second_update_at_the_same_time_changes_nothing_and_the_start_is_the_plant_pose():
    plant = RobotinoPlant(ROBOT, state0=np.array([1.0, 0, 2.0, 0, 0.5, 0, 0, 0, 0]))
    odometry = EncoderOdometry(plant, CPR)
    assert odometry.update() == ((1.0, 2.0, 0.5), (0.0, 0.0, 0.0))
    plant.step(np.array([6.0, 6.0, 6.0]), TS)
    first = odometry.update()
    assert odometry.update() == first


@pytest.mark.unit
@pytest.mark.parametrize("kwargs, message", [
    ({"model": "lidar"}, "odometry model"),
    ({"model": "encoders", "counts_per_rev": 0}, "counts_per_rev"),
    ({"model": "encoders", "counts_per_rev": 2.5}, "counts_per_rev"),
    ({"model": "encoders", "slip_std": -0.1}, "slip_std"),
    ({"model": "encoders", "slip_std": math.nan}, "slip_std"),
])
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(EncoderError, match=message):
        odometry_source(RobotinoPlant(ROBOT), **kwargs)


@pytest.mark.unit
def test_ideal_source_is_the_plant():
    plant = RobotinoPlant(ROBOT)
    assert odometry_source(plant, "ideal") is plant


@pytest.mark.unit
def test_period_mean_filter_reproduces_the_encoder_pose_and_the_trapezoid_lags():
    """Noise-free encoder odometry of a plant under varying voltages: the pose filter with the period_mean
    predictor predicts each dead-reckoned pose exactly (estimate = measured pose to 1e-12), the trapezoid not.
    """
    from robotino_geom_mpc.control.motion_controller import state_from_odometry
    from robotino_geom_mpc.control.estimator import OdometryFilter

    plant = RobotinoPlant(ROBOT)
    odometry = EncoderOdometry(plant, CPR)
    filters = {twist: OdometryFilter(TS, 0.5, twist) for twist in ("period_mean", "instantaneous")}
    errors = {twist: 0.0 for twist in filters}
    rng = np.random.default_rng(5)
    for _ in range(300):
        pose, twist = odometry.update()
        X = state_from_odometry(pose, twist)
        for name, filt in filters.items():
            errors[name] = max(errors[name], np.abs(np.subtract(filt.update(*X), pose)).max())
        plant.step(rng.uniform(-8.0, 8.0, 3), TS)
    assert errors["period_mean"] < 1e-12
    assert errors["instantaneous"] > 1e-5


@pytest.mark.unit
def test_paper_circle_with_encoder_odometry_meets_the_issue_16_target():
    """Issue 16, item 3: odom-frame RMS tracking error <= 0.3 mm, peak current <= nominal + 2 % (0.877 A)."""
    from robotino_geom_mpc.offline.results import compute_metrics
    from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario

    m = compute_metrics(run_scenario(RunConfig("paper-circle", ROBOT, CONTROL, odometry="encoders")))
    assert m["rms_position_error_odom_m"] <= 0.3e-3
    assert m["peak_current_a"] <= 1.02 * ROBOT.nominal_current_a


@pytest.mark.unit
def test_encoder_odometry_gives_the_controller_the_period_mean_predictor(monkeypatch):
    """run_scenario and node_arguments set control.odometry_twist = period_mean with encoders, and only then."""
    import robotino_geom_mpc.offline.simulation as simulation
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import node_arguments

    seen = []
    real = simulation.ControllerLoop
    spy = lambda robot, control, *args, **kwargs: seen.append(control) or real(robot, control, *args, **kwargs)  # noqa: E731
    monkeypatch.setattr(simulation, "ControllerLoop", spy)
    for odometry in ("encoders", "ideal"):
        simulation.run_scenario(simulation.RunConfig("paper-circle", ROBOT, CONTROL, duration_s=0.05,
                                                     odometry=odometry))
    assert CONTROL.odometry_twist == "instantaneous"  # the preset's
    assert [c.odometry_twist for c in seen] == ["period_mean", "instantaneous"]
    assert seen[0] == replace(CONTROL, odometry_twist="period_mean")
    setting = "control.odometry_twist:=period_mean"
    for odometry, wanted in (("encoders", True), ("ideal", False)):
        args = node_arguments("paper-circle", default_params_file(), 1.0, True, odometry=odometry)
        assert (setting in args["controller_node"]) is wanted
        assert not any(setting in argv for name, argv in args.items() if name != "controller_node")
        assert f"odometry_model:={odometry}" in args["plant_node"]


@pytest.mark.ros
def test_lockstep_loop_with_encoder_odometry_equals_the_offline_loop(tmp_path):
    """The three node processes started with node_arguments(odometry="encoders") reproduce
    run_scenario(odometry="encoders") to 1e-6: the plant's dead reckoning and the controller's predictor.
    """
    from probe import PROBE_WAIT_FOR, ProbeSpinner
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import NodeGroup, node_arguments
    from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario

    duration = 3.0
    probe = ProbeSpinner()
    try:
        with NodeGroup(log_dir=tmp_path) as group:
            args = node_arguments("paper-circle", default_params_file(), duration, True,
                                  wait_for=list(PROBE_WAIT_FOR), odometry="encoders")
            loop = ("trajectory_node", "controller_node", "plant_node")
            nodes = {name: group.start(name, args[name]) for name in loop}
            assert group.wait(nodes["plant_node"], 240.0), nodes["plant_node"].stderr_tail()
            assert nodes["plant_node"].popen.returncode == 0
        probe.wait_for_ticks(round(duration / TS))
        dds = probe.probe.run_data("paper-circle")
    finally:
        probe.close()
    offline = run_scenario(RunConfig("paper-circle", ROBOT, CONTROL, duration_s=duration, odometry="encoders"))
    assert dds.n == offline.n == round(duration / TS)
    for name in ("pose", "reference", "currents", "voltages"):
        np.testing.assert_allclose(getattr(dds, name), getattr(offline, name), rtol=1e-6, atol=1e-9, err_msg=name)
