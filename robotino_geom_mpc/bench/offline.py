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
           "lockstep, as simulate drives it: planar inputs; and fed the messages, the yaw as quaternions, as the nodes "
           "feed it) beside the kernels alone (MotionController.step), on the same RobotLoop, paper-circle: wall "
           "times, ratios, pose difference")
def bench_offline_loop(quick: bool) -> dict[str, float]:
    """What driving `loop.controller_loop.ControllerLoop` costs per tick against the kernels called directly
    (`MotionController.step` on the exact reference rows), each with the same `loop.robot_loop.RobotLoop` and loop
    body: fed in process (`offline.lockstep.LockstepController`, `simulate`'s plain tick: `PlanarPreview`,
    `PlanarOdometry`) and fed the messages as the nodes get them (`PreviewRows.at`, `odometry_event`: the yaw as
    a quaternion), the case for the planar inputs. The runs' poses must agree (max |diff| reported; paper-circle's
    heading stays 0, so exactly). Medians of alternating repeats.
    """
    import time
    from collections.abc import Callable, Sequence

    import numpy as np

    from robotino_geom_mpc.control.motion_controller import MotionController, state_from_odometry
    from robotino_geom_mpc.loop.controller_loop import QUIET, ControllerLoop
    from robotino_geom_mpc.loop.events import Command, Now
    from robotino_geom_mpc.loop.robot_loop import PoseNoise, RobotLoop, VoltageDrive
    from robotino_geom_mpc.model.plant import RobotinoPlant
    from robotino_geom_mpc.offline.lockstep import LockstepController, PreviewRows, odometry_event
    from robotino_geom_mpc.offline.simulation import run_ticks
    from robotino_geom_mpc.scenarios import get_scenario

    duration_s, repeats = (5.0, 1) if quick else (22.0, 5)
    robot, control = load_params()
    spec = get_scenario("paper-circle")
    Ts, N = control.period_s, control.horizon
    Ts_ns, n = round(Ts * 1e9), run_ticks(duration_s, Ts)
    Triple = tuple[float, float, float]
    Controller = Callable[[int, Triple, Triple], Sequence[float]]  # tick k's command for its odometry

    def kernels() -> Controller:
        targets = spec.make_reference().position(np.arange(n + N + 1) * Ts)
        controller = MotionController(spec.controller_model(robot), control)
        controller.start_at(*targets[0].tolist())  # robot and reference start together
        return lambda k, pose, twist: controller.step(state_from_odometry(pose, twist), targets[k + 1:k + N + 1]
                                                      ).voltages

    def loop_and_previews() -> tuple[ControllerLoop, PreviewRows]:
        loop = ControllerLoop(spec.controller_model(robot), control, Now(0, 0), lockstep=True, listeners=QUIET)
        return loop, PreviewRows(spec.make_reference(), Ts, Ts_ns, loop.preview_points, n)

    def planar() -> Controller:
        return LockstepController(*loop_and_previews()).command

    def messages() -> Controller:
        loop, previews = loop_and_previews()

        def command(k: int, pose: Triple, twist: Triple) -> Sequence[float]:
            now = Now(k * Ts_ns, k * Ts_ns)
            loop.on_preview(previews.at(k), now)
            return next(o.values for o in loop.on_odometry(odometry_event(k * Ts_ns, pose, twist), now)
                        if isinstance(o, Command))
        return command

    def run(controller: Callable[[], Controller]) -> tuple[float, np.ndarray]:
        begin = time.perf_counter()
        command = controller()
        plant = RobotinoPlant(robot)
        robot_loop = RobotLoop(plant, plant, VoltageDrive(plant), Ts,
                               PoseNoise((spec.noise.position_m, spec.noise.yaw_rad), 0, n))
        measure, drive, poses = robot_loop.measure, robot_loop.drive, []
        for k in range(n):
            poses += plant.pose
            drive(command(k, *measure()))
        return time.perf_counter() - begin, np.array(poses)

    run(kernels)  # the plant's matrices cached before any run is timed
    walls: dict[str, list[float]] = {"kernels": [], "planar": [], "messages": []}
    difference = 0.0
    for _ in range(repeats):
        wall, alone = run(kernels)
        walls["kernels"].append(wall)
        for name, side in (("planar", planar), ("messages", messages)):
            wall, through = run(side)
            walls[name].append(wall)
            difference = max(difference, float(np.abs(through - alone).max()))
    kernel, loop, message = (float(np.median(walls[name])) for name in ("kernels", "planar", "messages"))
    return {"offline_loop_kernels_s": kernel, "offline_loop_controller_loop_s": loop,
            "offline_loop_ratio": loop / kernel, "offline_loop_messages_s": message,
            "offline_loop_messages_ratio": message / kernel, "offline_loop_max_pose_diff_m": difference}


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
