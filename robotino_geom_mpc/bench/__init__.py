"""Every benchmark of `robotino-geom-mpc bench`, each measured side by side with a peer in the same run.

Modules (each registers its benchmarks in `registry.REGISTRY`, run in this order):

* `controller_step`: one full control step of `MotionController.step`
  (three MPCs, eq. 56, then T(theta), eqs. 33-37, then the inverse drive)
  against OSQP solving the same three per-axis MPC problems (eqs. 50-54,
  warm-started, tight tolerances) on the same inputs, as three problems
  (the paper's three MPCs; the headline ratio) and stacked into one
  block-diagonal QP; all must give the same commanded accelerations u.
* `float_path`: one control step and each of its kernels on Python floats (the nodes' and `simulate`'s per-tick
  path) beside the array kernels that serve a batch (the study's), both on one run: is the float path needed?
* `offline`: the offline closed loop's real-time factor on paper-circle, and
  the nodes over DDS (`dds`: lockstep real-time factor, realtime missed
  ticks and latency, each beside the bare rclpy round trip of `roundtrip`;
  skipped when ROS 2 is missing).
* `cdr`: the CDR fast path (`ros.cdr` templates and layouts) against
  rclpy's (de)serialization and rosbags' decoder, per message of the loop.
* `study`: the aggregate real-time factor of a short Monte-Carlo study
  (`robotino_geom_mpc.offline.study`) on all cores, beside `offline`'s one run.
* `end_to_end`: ``robotino-geom-mpc run`` on 20 s of paper-circle as a
  user starts it (``run_end_to_end_s``) and its loop with the recorder,
  beside the loop without it and a bare rclpy process start.
* `recorder_cpu`: the recorder's CPU time per message of a run's topics,
  beside bare rclpy readers (executor, wait set) of the same messages.
* `networked`: the realtime loop with plans (over the wifi link, and on one host without a link) beside the
  uncompensated controller, RMS position error from the bags.
* `soak` (only by name: ``bench --only soak [--duration S]``): the realtime
  loop with the recorder for 30 minutes, per 5-minute window; the controller
  killed and restarted 200 times (`restarts`); ``run`` 100 times in a row.
* `fleet` (only by name: ``bench --only fleet``): N robots in realtime at 100 Hz (N = 1, 5, 10, 20) through the
  fleet's three processes (`ros.fleet`) beside N separate loops: per-robot CPU and missed ticks.
* `fleet_batch`: B robots' control steps one at a time (each robot's loop) beside one batched step over the B
  (`MotionControllerBatch`), per robot and tick, B = 1, 5, 10, 20.
* `host_steal` samples the hypervisor's steal beside the realtime run;
  `startup_stalls` is a script (``python -m robotino_geom_mpc.bench.startup_stalls``).
"""

# registration, in the order `bench` runs them
from robotino_geom_mpc.bench import controller_step, offline  # noqa: F401, I001
from robotino_geom_mpc.bench import float_path  # noqa: F401
from robotino_geom_mpc.bench import study  # noqa: F401
from robotino_geom_mpc.bench import cdr  # noqa: F401
from robotino_geom_mpc.bench import constrained  # noqa: F401
from robotino_geom_mpc.bench import end_to_end  # noqa: F401
from robotino_geom_mpc.bench import recorder_cpu  # noqa: F401
from robotino_geom_mpc.bench import networked  # noqa: F401
from robotino_geom_mpc.bench import soak  # noqa: F401
from robotino_geom_mpc.bench import fleet  # noqa: F401
from robotino_geom_mpc.bench import fleet_batch  # noqa: F401
from robotino_geom_mpc.bench.registry import REGISTRY, BenchmarkError, BenchmarkSkipped, benchmark, run_benchmarks

__all__ = ["REGISTRY", "BenchmarkError", "BenchmarkSkipped", "benchmark", "run_benchmarks"]
