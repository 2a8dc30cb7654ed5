"""A probe of the lockstep loop for tests: keeps ground truth, preview point 0, currents and voltages per tick."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.decode import unwrap_near
from robotino_geom_mpc.ros.messages import quaternion_to_yaw, stamp_to_ns

# the plant's `processes.LOCKSTEP_WAIT_FOR` with the probe
PROBE_WAIT_FOR = ("odom:1", "/clock:1", "reference_preview:2", "wheel_voltages:2", "ground_truth/odom:1",
                  "wheel_currents:1")

# keep-all and reliable, as the recorder: the probe may lag behind the loop (its Python decoding of a
# preview costs more than the loop's tick) but loses no sample. A keep-last queue, however deep, drops
# its oldest samples once the probe lags by more than its depth: a preview of tick 400 went missing so.
PROBE_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


class LoopProbe(Node):
    """Subscribes the loop's topics and keeps what arrives (ground truth, preview point 0, currents, voltages)."""

    def __init__(self, context: Context) -> None:
        super().__init__("robotino_loop_probe", context=context)
        self.truth: dict[int, tuple[float, float, float]] = {}
        self.reference: dict[int, tuple[float, float, float]] = {}
        self.currents: list[list[float]] = []
        self.voltages: list[list[float]] = []
        self.create_subscription(Odometry, "ground_truth/odom", self._on_truth, PROBE_QOS)
        self.create_subscription(MultiDOFJointTrajectory, "reference_preview", self._on_preview, PROBE_QOS)
        self.create_subscription(Float64MultiArray, "wheel_currents", self._on_currents, PROBE_QOS)
        self.create_subscription(Float64MultiArray, "wheel_voltages", self._on_voltages, PROBE_QOS)
        self._theta = 0.0

    def _on_truth(self, msg: Odometry) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        if stamp not in self.truth:
            p = msg.pose.pose.position
            self._theta = unwrap_near(quaternion_to_yaw(msg.pose.pose.orientation), self._theta)
            self.truth[stamp] = (p.x, p.y, self._theta)

    def _on_preview(self, msg: MultiDOFJointTrajectory) -> None:
        tf = msg.points[0].transforms[0]
        self.reference[stamp_to_ns(msg.header.stamp)] = (
            tf.translation.x, tf.translation.y, quaternion_to_yaw(tf.rotation))

    def _on_currents(self, msg: Float64MultiArray) -> None:
        self.currents.append(list(msg.data))

    def _on_voltages(self, msg: Float64MultiArray) -> None:
        self.voltages.append(list(msg.data))

    def run_data(self, scenario: str, params_file: str | os.PathLike | None = None):
        """The lockstep run as `results.RunData` (one sample per tick; plant currents, controller voltages)."""
        from robotino_geom_mpc.offline.results import RunData

        robot, control = load_params(params_file)
        stamps = sorted(self.truth)
        n = min(len(stamps), len(self.currents), len(self.voltages))
        stamps = stamps[:n]
        t = np.array(stamps, dtype=float) * 1e-9
        ref = np.array([self.reference[s] for s in stamps])
        ref[:, 2] = np.unwrap(ref[:, 2])
        return RunData(
            scenario=scenario,
            t=t,
            pose=np.array([self.truth[s] for s in stamps]),
            reference=ref,
            currents=np.array(self.currents[:n]),
            voltages=np.array(self.voltages[:n]),
            control_period_s=control.period_s,
            horizon=control.horizon,
            nominal_current_a=robot.nominal_current_a,
            supply_voltage_v=robot.supply_voltage_v,
        )


class ProbeSpinner:
    """An rclpy context with the probe, spun in a background thread."""

    def __init__(self) -> None:
        from rclpy.executors import SingleThreadedExecutor

        self.context = Context()
        rclpy.init(context=self.context)
        self.probe = LoopProbe(self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.probe)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # context shut down while spinning
            pass

    def wait_for_ticks(self, ticks: int, timeout_s: float = 60.0) -> None:
        """Wait until the probe holds `ticks` samples of every topic: after the plant's exit the probe's thread
        still takes what DDS delivered (on a loaded host, hundreds of samples take it a second and more).
        """
        probe, deadline = self.probe, time.monotonic() + timeout_s
        while min(len(probe.truth), len(probe.reference), len(probe.currents), len(probe.voltages)) < ticks:
            assert time.monotonic() < deadline, (f"the probe has {len(probe.truth)} truth, {len(probe.reference)} "
                                                 f"previews, {len(probe.currents)} currents, {len(probe.voltages)} "
                                                 f"voltages of {ticks} ticks after {timeout_s:g} s")
            time.sleep(0.02)

    def close(self) -> None:
        self.context.try_shutdown()
        if self.thread.is_alive():
            self.thread.join(timeout=5.0)
        self.executor.shutdown()
        self.probe.destroy_node()


