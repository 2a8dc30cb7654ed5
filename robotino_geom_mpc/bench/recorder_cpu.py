"""Benchmark ``recorder_cpu``: the recorder's CPU time per message, beside bare rclpy readers of the same messages.

One publisher process (`recorder_load`, ``--role publisher``) sends, per tick of a fixed rate, what one lockstep tick
of a recorded run carries: 11 messages on 10 topics with the run's types and
sizes (`tick_messages`: two odometries, the reference preview, the predicted
path, voltages, currents, diagnostics, joint states, /clock and two /tf),
reliable keep-all, serialized once and published as bytes. Three readers of
all of them run at the same time, so they see the same machine:

* the recorder node (`recording.recorder_node`, recording these topics);
* ``take_executor``: a bare rclpy node with raw subscriptions whose
  callbacks do nothing, spun by ``SingleThreadedExecutor.spin_once``
  (what the recorder did before it had its own wait loop);
* ``take_waitset``: raw takes from one rclpy wait set, every ready sample of
  every subscription per wake-up: the floor of taking in Python.

The publisher samples each reader's CPU time (user + system, from
``/proc/PID/stat``) just before the first tick and, once every reader
acknowledged every sample, when the readers are idle again; the difference
over the messages sent is the CPU per message (process start, discovery and
closing the bag are outside it). The processes run on a domain of their own
(random ROS_DOMAIN_ID, localhost discovery): no other traffic is counted.
The readers' counts (the bag's, read back with `BagReader`, and the bare
readers' own) must equal the messages sent: a lost message fails the run.
"""

from __future__ import annotations

import importlib.util
import json
import random
import tempfile
from pathlib import Path
from typing import Any

from robotino_geom_mpc.bench.registry import BenchmarkError, BenchmarkSkipped, benchmark, wait_for_run
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

__all__ = ["READERS", "bench_recorder_cpu"]

READERS = ("recorder", "take_executor", "take_waitset")  # the takers: `recorder_load.TAKERS`


def bench_recorder_cpu(ticks: int = 2000, rate_hz: float = 400.0, log_dir: Path | None = None,
                       recorder_parameters: dict[str, Any] | None = None) -> dict[str, float]:
    """One run of the publisher and the three `READERS`: CPU per message [us] of each and the recorder's ratios.

    `recorder_parameters` are given to the recorder beside its output and topics.

    Raises
    ------
    BenchmarkError
        If a process fails or a reader did not get every message.
    """
    from robotino_geom_mpc.bench.recorder_load import MODULE, tick_messages  # not at import: run with -m
    from robotino_geom_mpc.recording.bag_reader import BagReader

    env = {"ROS_DOMAIN_ID": str(random.SystemRandom().randint(102, 200)), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    with tempfile.TemporaryDirectory(prefix="recorder_cpu_") as tmp, NodeGroup(log_dir=log_dir, env=env) as group:
        out = Path(tmp)
        readers = {"recorder": group.start("recorder_node", ros_args(overrides={
            "output": str(out / "bag"), "topics": list(dict(tick_messages())), **(recorder_parameters or {})}))}
        for role in READERS[1:]:
            readers[role] = group.start(role, ["--role", role, "--report", str(out / f"{role}.json")], MODULE)
        watch = ",".join(f"{name}={proc.popen.pid}" for name, proc in readers.items())
        publisher = group.start("publisher", ["--role", "publisher", "--ticks", str(ticks), "--rate", str(rate_hz),
                                              "--watch", watch, "--report", str(out / "publisher.json")], MODULE)
        wait_for_run(group, publisher, 120.0 + 2 * ticks / rate_hz, "recorder_cpu publisher")
        group.stop()
        group.check()
        report = json.loads((out / "publisher.json").read_text())
        sent = report["messages"]
        with BagReader(out / "bag") as bag:
            counts = {"recorder": bag.message_count}
        for role in READERS[1:]:
            counts[role] = json.loads((out / f"{role}.json").read_text())["count"]
    lost = {name: sent - count for name, count in counts.items() if count != sent}
    if lost:
        raise BenchmarkError(f"recorder_cpu: of {sent} messages sent, these readers lost some: {lost}")
    us = {name: 1e6 * report["cpu_s"][name] / sent for name in READERS}
    return {"recorder_cpu_us_per_message": us["recorder"],
            "take_executor_cpu_us_per_message": us["take_executor"],
            "take_waitset_cpu_us_per_message": us["take_waitset"],
            "recorder_over_take_executor": us["recorder"] / us["take_executor"],
            "recorder_over_take_waitset": us["recorder"] / us["take_waitset"],
            "recorder_cpu_messages_per_s": sent / report["wall_s"]}


@benchmark("recorder_cpu", "the recorder's CPU per message (10 topics of a run) beside bare rclpy readers")
def _recorder_cpu(quick: bool) -> dict[str, float]:
    if importlib.util.find_spec("rclpy") is None:
        raise BenchmarkSkipped("rclpy is not importable")
    return bench_recorder_cpu(ticks=600 if quick else 2000)


