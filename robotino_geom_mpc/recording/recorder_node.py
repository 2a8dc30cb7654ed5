"""Recorder node: every topic of the running system (or a list) into a rosbag2-compatible MCAP bag.

Topics are picked up as they appear (the graph is polled every
``discovery_period_s``) and subscribed serialized (``raw=True``): the CDR
bytes go into the bag without being deserialised. The subscription QoS
follows the publishers' offers as rosbag2 does (reliable / transient local
only when every publisher offers it, so the latched ``reference_path`` is
captured), with a keep-all history (``qos_depth``, see
`qos.adapt_request_to_offers`); hidden topics (a name component starting
with ``_``) are skipped. A recorder in a namespace (one robot of several)
records by default its namespace's topics and the shared ``/tf`` and
``/tf_static`` only, not the other robots'. Messages published before the recorder has matched
a topic are not in the bag (as with ``ros2 bag record``): a lockstep run
makes the plant wait for the recorder's subscriptions (``lockstep_wait_for``).

CPU: the recorder does not spin its recording subscriptions with an rclpy
executor but waits on one wait set of its own (`RecorderNode.spin`) and,
at most every `TAKE_PERIOD_S` (0.02 s), takes every sample of every topic in one
batch (the samples in between wait in DDS's keep-all readers): about 40 us
of CPU per message against 150 us with the executor (`bench.recorder_cpu`).

Times: ``log_time`` is the receive time on the system clock (the DDS
reception timestamp), as ``ros2 bag record`` does by default; with
``use_sim_time:=true`` it is the node's ROS time (/clock) at reception, as
``ros2 bag record --use-sim-time`` does. ``publish_time`` is always the
publisher's DDS source timestamp (system clock), so causal order between
nodes on one machine survives in the bag.

Run parameters: started with the system's ``--params-file`` the recorder
receives the ``/**`` robot/motor/control parameters too, and from the launch
and `run` the controller's ``chain.*`` (identify's file) and the loop settings
they give the controller (`params.specs.RECORDED_CONTROLLER_SPECS`, e.g. a realtime
fleet's ``reference_timeout_s``); it stores them (and
its ``scenario`` parameter) in an MCAP metadata record ``robotino_geom_mpc``
written when the bag opens, and in metadata.yaml's custom_data, so a
recording carries what `report` and `regress` need.

Crash safety: the chunk in progress is closed and handed to the OS every
``flush_period_s`` (default 0.5 s) and whenever it reaches
``chunk_size_bytes``; after SIGKILL at most that much (and what was in transit) is lost, `BagReader`
reads the rest and ``robotino-geom-mpc reindex`` writes a finalised MCAP
and metadata.yaml from it. metadata.yaml is written at the end only:
rosbags does not open an MCAP without footer even with a metadata.yaml
next to it (test_reindex), so keeping one current would not help. SIGINT/SIGTERM stop the node cleanly: messages
already queued are taken and written, then the summary, the indexes and
metadata.yaml.
"""

from __future__ import annotations

import gc
import json
import sys
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node

from robotino_geom_mpc.params.specs import ALL_SPECS, RECORDED_CONTROLLER_SPECS
from robotino_geom_mpc.recording.bag_writer import BagWriter, default_bag_name, default_compression
from robotino_geom_mpc.recording.bagfile import BagError
from robotino_geom_mpc.recording.definitions import message_class
from robotino_geom_mpc.ros.bag_qos import adapt_request_to_offers, profile_to_dict
from robotino_geom_mpc.system.signals import STOP, ignore_stop_signals
from robotino_geom_mpc.ros.spin import start_rclpy

__all__ = ["DRAIN_LIMIT_S", "TAKE_PERIOD_S", "WAIT_TIMEOUT_NS", "RecorderNode", "main"]

DRAIN_LIMIT_S = 60.0  # at stop: the longest the recorder keeps taking samples its readers still hold
# shortest time between two takes: what arrives meanwhile waits in the keep-all readers, then goes in one batch
TAKE_PERIOD_S = 0.02
WAIT_TIMEOUT_NS = 50_000_000  # the recording loop's longest wait: how soon it sees a stop signal


class _OwnLoop(CallbackGroup):
    """The recording subscriptions' group: never executed by an executor (`RecorderNode.spin` takes them)."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass

def _hidden(topic: str) -> bool:
    return any(part.startswith("_") for part in topic.split("/") if part)

# the run parameters the recorder declares and stores: the robot, the control, the chain, the controller loop's
# settings (what `regress` replays)
_STORED = (*ALL_SPECS, *RECORDED_CONTROLLER_SPECS)

class RecorderNode(Node):
    """Records topics serialized into a `BagWriter`; see the module docstring for the behaviour."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("recorder", **kwargs)
        ro = {"read_only": True}
        self.declare_parameter("output", "", ParameterDescriptor(
            description="Bag directory to create (default rosbag2_YYYY_MM_DD-HH_MM_SS in the working directory)", **ro))
        self.declare_parameter("topics", [""], ParameterDescriptor(
            description="Topics to record; empty: every (non-hidden) topic of the system, as it appears",
            type=ParameterType.PARAMETER_STRING_ARRAY, **ro))
        self.declare_parameter("discovery_period_s", 0.1, ParameterDescriptor(
            description="Period of the graph polling for new topics [s]",
            floating_point_range=[FloatingPointRange(from_value=0.01, to_value=10.0)], **ro))
        self.declare_parameter("flush_period_s", 0.5, ParameterDescriptor(
            description="Longest time a received message waits in memory before its chunk is written [s]",
            floating_point_range=[FloatingPointRange(from_value=0.01, to_value=60.0)], **ro))
        self.declare_parameter("chunk_size_bytes", 512 * 1024, ParameterDescriptor(
            description="Uncompressed size after which an MCAP chunk is closed [bytes]",
            integer_range=[IntegerRange(from_value=1024, to_value=64 * 1024 * 1024, step=1)], **ro))
        self.declare_parameter("compression", default_compression(), ParameterDescriptor(
            description="Chunk compression: zstd, lz4 or none", additional_constraints="zstd|lz4|none", **ro))
        self.declare_parameter("qos_depth", 0, ParameterDescriptor(
            description="History of the recording subscriptions: 0 keep-all (lossless, see recording.qos), "
            "else keep-last with this depth",
            integer_range=[IntegerRange(from_value=0, to_value=100000, step=1)], **ro))
        self.declare_parameter("scenario", "", ParameterDescriptor(
            description="Scenario name stored with the run parameters (for reports)", **ro))
        for spec in _STORED:  # filled from the system's --params-file (/** section) and the chain's; stored, not used
            self.declare_parameter(spec.name, None, ParameterDescriptor(
                description=f"{spec.description} (stored in the bag)", dynamic_typing=True, **ro))

        p = self.get_parameter
        compression = p("compression").value
        if compression not in ("zstd", "lz4", "none"):
            raise BagError(f"parameter 'compression' must be zstd, lz4 or none, got {compression!r}")
        self._wanted = {self.resolve_topic_name(t) for t in p("topics").value if t} or None
        namespace = self.get_namespace().rstrip("/")
        self._own = (namespace + "/", ("/tf", "/tf_static")) if namespace else None
        self._depth = int(p("qos_depth").value)
        output = p("output").value or default_bag_name()
        self.writer = BagWriter(output, compression=compression, chunk_size=int(p("chunk_size_bytes").value))
        self._store_run_parameters()
        self._channels: dict[str, int] = {}
        self._recording_subs: list[Any] = []
        self._own_loop = _OwnLoop()
        self._use_sim_time = bool(p("use_sim_time").value)
        # with sim time a sample's log_time is the /clock time at its take: no waiting, so it stays as fresh
        self._take_period = 0.0 if self._use_sim_time else TAKE_PERIOD_S
        self._discover()
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # not ROS time: with use_sim_time, /clock may not run yet
        self.create_timer(float(p("discovery_period_s").value), self._discover, clock=steady)
        self.create_timer(float(p("flush_period_s").value), self._flush, clock=steady)
        self.get_logger().info(f"recording into {Path(output).resolve()} ({compression})")

    def _store_run_parameters(self) -> None:
        values = {}
        for spec in _STORED:
            value = self.get_parameter(spec.name).value
            if value is not None:
                values[spec.name] = value
        self.writer.store_run_metadata({"scenario": self.get_parameter("scenario").value,
                                        "parameters": json.dumps(values, sort_keys=True)})

    def _records(self, name: str) -> bool:
        """Whether `name` is wanted: listed in ``topics``, or else in this recorder's namespace (or /tf)."""
        if self._wanted is not None:
            return name in self._wanted
        return self._own is None or name.startswith(self._own[0]) or name in self._own[1]

    def _discover(self) -> None:
        """Subscribe every wanted topic that has a publisher and is not recorded yet."""
        for name, types in self.get_topic_names_and_types():
            if name in self._channels or _hidden(name) or not self._records(name):
                continue
            infos = self.get_publishers_info_by_topic(name)
            if not infos:
                continue
            type_name = types[0]
            if len(types) > 1:
                self.get_logger().warn(f"topic {name} has several types {types}; recording {type_name}")
            try:
                cls = message_class(type_name)
                channel = self.writer.add_topic(
                    name,
                    type_name,
                    [profile_to_dict(i.qos_profile) for i in infos],
                    str(infos[0].topic_type_hash),
                )
            except BagError as exc:
                self.get_logger().error(f"cannot record {name}: {exc}")
                self._channels[name] = -1
                continue
            self._channels[name] = channel
            qos = adapt_request_to_offers([i.qos_profile for i in infos], self._depth)
            self._recording_subs.append(self.create_subscription(
                cls, name, self._callback(channel), qos, raw=True, callback_group=self._own_loop,
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False)))
            self.get_logger().info(f"recording {name} [{type_name}]")

    def _callback(self, channel: int):
        def on_message(data: bytes, info: dict[str, int]) -> None:
            if self._use_sim_time:
                log_time = self.get_clock().now().nanoseconds
            else:
                log_time = info["received_timestamp"]
            self.writer.write(channel, log_time, data, info["source_timestamp"],
                              info.get("publication_sequence_number", 0))

        return on_message

    def _flush(self) -> None:
        """Hand the chunk to the OS with every sample received so far: those waiting for the next batched take
        (`TAKE_PERIOD_S`) too, so that a kill loses at most the last flush period.
        """
        self._take_all(self._recording_subs)
        self.writer.flush()

    def _take_all(self, subscriptions: list[Any]) -> int:
        """Write every sample the readers of `subscriptions` hold now; returns the count."""
        taken = 0
        for sub in subscriptions:
            take, msg_type, on_message = sub.handle.take_message, sub.msg_type, sub.callback
            while (sample := take(msg_type, True)) is not None:
                on_message(*sample)  # (data, info)
                taken += 1
        return taken

    def spin(self, executor: SingleThreadedExecutor, stop: Any) -> None:
        """Record until `stop` (an Event) is set: one wait set, every ready sample of every topic per wake-up.

        The recording subscriptions are in a callback group no executor runs (`_OwnLoop`): rclpy's executor
        rebuilds its wait set and makes a task for each message it takes, several times the take itself
        (`bench.recorder_cpu`). The node's other entities (timers, services, /clock of the time source) are in
        the same wait set; when one is ready, or the wait times out, `executor` runs what is ready.
        """
        shape: tuple[list[Any], list[Any], list[Any]] | None = None
        wait_set: Any = None  # an rclpy WaitSet (its C++ module has no types)
        own: set[int] = set()
        entries: list[tuple[Any, Any]] = []
        last_take = 0.0
        with ExitStack() as handles:
            while not stop.is_set():
                current = (list(self.subscriptions), list(self.timers), list(self.services))
                if current != shape:  # a topic was discovered (or the time source subscribed /clock)
                    handles.close()
                    shape = current
                    wait_set, own, entries = self._wait_set(handles, *current)
                wait_set.clear_entities()
                for add_entity, handle in entries:
                    add_entity(handle)
                wait_set.wait(WAIT_TIMEOUT_NS)
                ready = wait_set.get_ready_entities("subscription")
                if any(p in own for p in ready):
                    time.sleep(max(0.0, last_take + self._take_period - time.monotonic()))
                    last_take = time.monotonic()
                    self._take_all(self._recording_subs)
                others = sum(1 for p in ready if p not in own)
                others += len(wait_set.get_ready_entities("timer")) + len(wait_set.get_ready_entities("service"))
                for _ in range(others if ready or others else 1):  # after a timeout: the executor's guards
                    executor.spin_once(timeout_sec=0)

    def _wait_set(self, handles: ExitStack, subs: list[Any], timers: list[Any],
                  services: list[Any]) -> tuple[Any, set[int], list[tuple[Any, Any]]]:
        """A wait set for all of the node's subscriptions, timers and services (their handles held in `handles`).

        Returns it, the pointers of the recording subscriptions and the (add function, handle) of each entity.
        """
        wait_set = _rclpy.WaitSet(len(subs), 0, len(timers), 0, len(services), 0, self.context.handle)
        entries = [(wait_set.add_subscription, s.handle) for s in subs]
        entries += [(wait_set.add_timer, t.handle) for t in timers]
        entries += [(wait_set.add_service, s.handle) for s in services]
        for _, handle in entries:
            handles.enter_context(handle)
        context = self.context.handle
        if context is None:
            raise RuntimeError("the recorder's ROS context is shut down")
        handles.enter_context(context)
        return wait_set, {s.handle.pointer for s in self._recording_subs}, entries

    def drain(self, limit_s: float) -> int:
        """Write every sample DDS has received and not yet handed over, until all readers are empty; returns the count.

        A keep-all reader can hold thousands of samples when a fast lockstep loop stops (the loop's
        keep-all writers waited for this recorder's acknowledgements, not for its writes), so the stop
        takes them directly from each subscription rather than spinning for a fixed time. `limit_s`
        bounds it when a live publisher keeps sending.
        """
        taken, deadline = 0, time.monotonic() + limit_s
        while time.monotonic() < deadline:
            count = self._take_all(self._recording_subs)
            taken += count
            if count == 0:
                return taken
        self.get_logger().warn(f"stopped draining after {limit_s:g} s ({taken} samples taken); later ones are lost")
        return taken

    def close(self) -> None:
        """Finish the bag (summary, indexes, metadata.yaml)."""
        self.writer.close()
        self.get_logger().info(f"bag closed: {self.writer.message_count} messages on {len(self._channels)} topics")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run robotino_geom_mpc recorder_node``: record until SIGINT/SIGTERM."""
    status = start_rclpy(args)
    if status is not None:
        return status
    try:
        node = RecorderNode()
    except BagError as exc:
        print(f"recorder_node: error: {exc}", file=sys.stderr)
        ignore_stop_signals()
        rclpy.shutdown()
        return 2
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        node.spin(executor, STOP)
        node.drain(DRAIN_LIMIT_S)
    finally:
        ignore_stop_signals()
        node.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        # the bag is closed: the interpreter's exit need not walk the heap (its last collection took over 5 s on a
        # loaded machine, past `ros2 launch`'s SIGINT-to-SIGTERM grace); the objects die with the process
        gc.freeze()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
