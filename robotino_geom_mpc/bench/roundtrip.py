"""A bare rclpy round trip between two processes: what transport and executors cost, with no control work.

Two processes, run as ``python -m robotino_geom_mpc.bench.roundtrip --role
plant|controller``, exchange what the lockstep loop exchanges on its
critical path, the way the nodes do it:

* the "plant" publishes a nav_msgs/Odometry (``odom`` -> ``base_link``,
  REP-105, the size of the plant's) as `CdrTemplate` bytes with a sequence
  number in the stamp, and waits for the answer before it sends the next;
* the "controller" reads the stamp in place (`messages.odometry_layout`, as
  the controller node does) and answers with a Float64MultiArray of 3
  values (`messages.three_values_template`) carrying the sequence number.

Both use the lockstep loop's QoS (`ros.qos`: ``publish_qos(lockstep=True)``
writers, keep-all; `CONTROL_QOS` readers; raw subscriptions) and its executor (`ros.spin.run_node`: the
events executor, the garbage collector frozen after start). A round trip
runs from just before packing the odometry to the start of the answer's
callback on the plant's steady clock, as the realtime plant times its
latency (`robotino_sim_node.loop_timing`). The lockstep loop's tick cannot
be shorter than one round trip (plus the preview the trajectory publishes
on /clock), so `bench.dds` sets the two side by side.

`bench_roundtrip` starts both processes (own process groups, always
stopped) and returns the median and p99 of the timed round trips.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from robotino_geom_mpc.bench.registry import BenchmarkError, wait_for_run
from robotino_geom_mpc.system.processes import NodeGroup

__all__ = ["ANSWER_TOPIC", "ODOM_TOPIC", "bench_roundtrip", "main", "nearest_rank", "read_roundtrip_report",
           "roundtrip_figures"]

ODOM_TOPIC = "bench_roundtrip/odom"  # own names: nothing else on the domain sees or disturbs them
ANSWER_TOPIC = "bench_roundtrip/wheel_voltages"
_START_POLL_S = 0.01  # the plant looks for the controller's endpoints this often until it starts
_SETTLE_S = 0.5  # then waits this long, so the endpoints the graph shows have matched
_RESEND_S = 0.5  # and publishes the pending round trip again after this long without an answer


def nearest_rank(sorted_values: list[float], q: float) -> float:
    """The `q`-th percentile (0..100) of `sorted_values`, nearest rank (as `LoopTiming.percentile_s`)."""
    if not sorted_values:
        raise ValueError("no values")
    return sorted_values[max(math.ceil(q / 100.0 * len(sorted_values)), 1) - 1]


def roundtrip_figures(samples_s: list[float]) -> dict[str, float]:
    """``roundtrip_us_median`` and ``roundtrip_us_p99`` (nearest rank) of round trips given in seconds."""
    ordered = sorted(samples_s)
    return {"roundtrip_us_median": 1e6 * nearest_rank(ordered, 50), "roundtrip_us_p99": 1e6 * nearest_rank(ordered, 99)}


def read_roundtrip_report(path: str | os.PathLike, count: int) -> list[float]:
    """The `count` round trips [s] the plant process wrote to `path`.

    Raises
    ------
    BenchmarkError
        If the file is missing or not the plant's report of `count` positive finite round trips.
    """
    try:
        samples = json.loads(Path(path).read_text())["roundtrip_s"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BenchmarkError(f"round trip: no report of the plant process in {path} ({exc})") from None
    if len(samples) != count or not all(isinstance(s, float) and math.isfinite(s) and s > 0 for s in samples):
        raise BenchmarkError(f"round trip: {path} does not hold {count} positive finite round trips")
    return samples


def bench_roundtrip(count: int = 2000, warmup: int = 200, timeout_s: float = 120.0) -> dict[str, float]:
    """Run `warmup` + `count` round trips between two processes; the median and p99 of the last `count` [us].

    Raises
    ------
    BenchmarkError
        If a process fails, the run does not end within `timeout_s` or the report is malformed.
    """
    with NodeGroup() as group:
        report = group.logs / "roundtrip.json"
        group.start("roundtrip_controller", ["--role", "controller"], module=__name__)
        plant = group.start("roundtrip_plant", ["--role", "plant", "--count", str(count), "--warmup", str(warmup),
                                                "--report", str(report)], module=__name__)
        wait_for_run(group, plant, timeout_s, f"round trip: {count + warmup} round trips")
        samples = read_roundtrip_report(report, count)
    return roundtrip_figures(samples)


def _nodes():
    """The two node classes (rclpy imported only in the processes that run them)."""
    from nav_msgs.msg import Odometry
    from rclpy.clock import Clock, ClockType
    from rclpy.node import Node
    from rclpy.task import Future
    from std_msgs.msg import Float64MultiArray

    from robotino_geom_mpc.ros.cdr import CdrTemplate
    from robotino_geom_mpc.ros.decode import ODOM_FIELDS
    from robotino_geom_mpc.ros.messages import VOLTAGE_LABEL, odometry_layout, odometry_message, \
        three_values_layout, three_values_template
    from robotino_geom_mpc.ros.qos import CONTROL_QOS, publish_qos
    from robotino_geom_mpc.ros.spin import monotonic

    class RoundTripPlant(Node):
        """Publishes odometry number k, waits for answer k, publishes k + 1; writes the round trips at the end."""

        def __init__(self, count: int, warmup: int, report: Path) -> None:
            super().__init__("bench_roundtrip_plant")
            self.count, self.warmup, self.report = count, warmup, report
            self.pub = self.create_publisher(Odometry, ODOM_TOPIC, publish_qos(lockstep=True))
            self.sub = self.create_subscription(Float64MultiArray, ANSWER_TOPIC, self._on_answer, CONTROL_QOS,
                                                raw=True)
            self.odom_cdr = CdrTemplate(odometry_message(), ODOM_FIELDS)
            self.answer_layout = three_values_layout(VOLTAGE_LABEL)
            self.values = [0.0] * (len(ODOM_FIELDS) - 2)
            self.seq, self.sent_at, self.ready_at = 0, math.inf, math.inf
            self.timed = True  # the pending round trip was sent once (not again after a loss)
            self.samples: list[float] = []
            self.done = Future()
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self.start_timer = self.create_timer(_START_POLL_S, self._try_start, clock=steady)
            self.resend_timer = self.create_timer(_RESEND_S, self._resend, clock=steady)

        def _try_start(self) -> None:
            now = monotonic()
            if not (self.pub.get_subscription_count() and self.sub.get_publisher_count()):
                self.ready_at = math.inf
            elif self.ready_at == math.inf:
                self.ready_at = now
            elif now - self.ready_at >= _SETTLE_S:
                self.start_timer.cancel()
                self._send()

        def _send(self, timed: bool = True) -> None:
            self.sent_at, self.timed = monotonic(), timed
            self.pub.publish(self.odom_cdr.pack(self.seq, 0, *self.values))

        def _resend(self) -> None:
            if self.start_timer.is_canceled() and monotonic() - self.sent_at > _RESEND_S:
                self._send(timed=False)  # the first went out before the reader matched: not a round trip to time

        def _on_answer(self, data: bytes) -> None:
            now = monotonic()
            values = self.answer_layout.read(data)
            if values is None or values[0] != self.seq or self.done.done():
                return
            if self.seq >= self.warmup and self.timed:
                self.samples.append(now - self.sent_at)
            if len(self.samples) == self.count:
                self.report.write_text(json.dumps({"roundtrip_s": self.samples}))
                self.done.set_result(True)
                return
            self.seq += 1
            self._send()

    class RoundTripController(Node):
        """Answers every odometry with its sequence number in three values; nothing else."""

        def __init__(self) -> None:
            super().__init__("bench_roundtrip_controller")
            self.pub = self.create_publisher(Float64MultiArray, ANSWER_TOPIC, publish_qos(lockstep=True))
            self.sub = self.create_subscription(Odometry, ODOM_TOPIC, self._on_odom, CONTROL_QOS, raw=True)
            self.odom_layout = odometry_layout()
            self.answer_cdr = three_values_template(VOLTAGE_LABEL)

        def _on_odom(self, data: bytes) -> None:
            values = self.odom_layout.read(data)
            if values is not None:
                self.pub.publish(self.answer_cdr.pack(float(values[0]), 0.0, 0.0))

    return RoundTripPlant, RoundTripController


def main(argv: list[str] | None = None) -> int:
    """Run one role of the round trip (``--ros-args ...`` go to rclpy)."""
    from robotino_geom_mpc.ros.spin import run_node

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--role", choices=("plant", "controller"), required=True)
    parser.add_argument("--count", type=int, default=2000, help="plant: timed round trips")
    parser.add_argument("--warmup", type=int, default=200, help="plant: round trips before them, not timed")
    parser.add_argument("--report", type=Path, help="plant: JSON file for the round trips [s]")
    argv = sys.argv[1:] if argv is None else argv
    args, ros = parser.parse_known_args(argv)
    if args.role == "plant" and (args.report is None or args.count < 1 or args.warmup < 0):
        parser.error("the plant needs --report, --count >= 1 and --warmup >= 0")
    plant, controller = _nodes()
    factory = (lambda: plant(args.count, args.warmup, args.report)) if args.role == "plant" else controller
    return run_node(factory, [sys.argv[0], *ros])


if __name__ == "__main__":
    raise SystemExit(main())
