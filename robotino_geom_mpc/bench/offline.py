"""Benchmarks ``offline_sim`` (the offline closed loop's real-time factor) and ``dds`` (the nodes over DDS)."""

from __future__ import annotations

from robotino_geom_mpc.bench.registry import BenchmarkSkipped, benchmark, median_per_call
from robotino_geom_mpc.params.files import load_params

__all__ = ["bench_dds", "bench_offline_loop", "bench_offline_sim"]


@benchmark("offline_sim", "offline closed loop (plant + controller + reference) on paper-circle, real-time factor")
def bench_offline_sim(quick: bool) -> dict[str, float]:
    """Simulated seconds per wall-clock second of `simulation.run_scenario` on paper-circle."""
    from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario

    duration_s, repeats = (5.0, 1) if quick else (60.0, 3)
    robot, control = load_params()
    (wall_s,) = median_per_call(
        [lambda: run_scenario(RunConfig("paper-circle", robot, control, duration_s=duration_s))],
        1,
        repeats,
    )
    return {
        "offline_sim_realtime_factor": duration_s / wall_s,
        "offline_sim_wall_s": wall_s,
        "offline_sim_duration_s": duration_s,
    }


@benchmark("offline_loop", "the offline plain loop's ticks through the controller's protocol (ControllerLoop in "
           "lockstep) beside the kernels alone (run_scenario), paper-circle: wall times, ratio, pose difference")
def bench_offline_loop(quick: bool) -> dict[str, float]:
    """What driving `loop.controller_loop.ControllerLoop` costs per tick against `simulation.run_scenario`'s loop,
    on the same `loop.robot_loop.RobotLoop`; the two runs' poses must agree (max |diff| reported).
    """
    import time

    import numpy as np

    from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
    from robotino_geom_mpc.loop.events import Now
    from robotino_geom_mpc.loop.robot_loop import PoseNoise, RobotLoop, VoltageDrive
    from robotino_geom_mpc.model.plant import RobotinoPlant
    from robotino_geom_mpc.offline.lockstep import LockstepController, PreviewRows
    from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario, run_ticks
    from robotino_geom_mpc.scenarios import get_scenario

    duration_s = 5.0 if quick else 22.0
    robot, control = load_params()
    spec = get_scenario("paper-circle")
    n, period_ns = run_ticks(duration_s, control.period_s), round(control.period_s * 1e9)

    def through_the_loop() -> np.ndarray:
        loop = ControllerLoop(spec.controller_model(robot), control, Now(0, 0), lockstep=True, listeners=QUIET)
        controller = LockstepController(loop, PreviewRows(spec.make_reference(), control.period_s, period_ns,
                                                          loop.preview_points, n))
        plant = RobotinoPlant(robot)
        robot_loop = RobotLoop(plant, plant, VoltageDrive(plant), control.period_s,
                               PoseNoise((spec.noise.position_m, spec.noise.yaw_rad), 0, n))
        poses = []
        for k in range(n):
            poses.append(plant.pose)
            robot_loop.drive(controller.command(k, *robot_loop.measure()))
        return np.array(poses)

    begin = time.perf_counter()
    kernels = run_scenario(RunConfig("paper-circle", robot, control, duration_s=duration_s))
    kernels_s = time.perf_counter() - begin
    begin = time.perf_counter()
    poses = through_the_loop()
    loop_s = time.perf_counter() - begin
    difference = float(np.abs(poses - kernels.pose).max())
    return {"offline_loop_kernels_s": kernels_s, "offline_loop_controller_loop_s": loop_s,
            "offline_loop_ratio": loop_s / kernels_s, "offline_loop_max_pose_diff_m": difference}


@benchmark("dds", "the nodes over DDS: lockstep real-time factor, realtime missed ticks and latency, "
           "each beside a bare rclpy round trip")
def bench_dds(quick: bool) -> dict[str, float]:
    """The figures of `bench.dds.dds_benchmarks`, skipped without ROS 2."""
    try:
        import rclpy  # noqa: F401  (the nodes need it; bench.dds itself does not import it)

        from robotino_geom_mpc.bench.dds import dds_benchmarks
    except ImportError as exc:
        raise BenchmarkSkipped(f"ROS 2 not available: {exc}") from None
    return dds_benchmarks(quick)
