"""Benchmarks ``offline_sim`` (the offline closed loop's real-time factor) and ``dds`` (the nodes over DDS)."""

from __future__ import annotations

from robotino_geom_mpc.bench.registry import BenchmarkSkipped, benchmark, median_per_call
from robotino_geom_mpc.params.files import load_params

__all__ = ["bench_dds", "bench_offline_sim"]


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
