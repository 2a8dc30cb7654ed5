"""The main loop every node runs: parameter files checked, rclpy init, the events executor, quiet exits on signals."""

from __future__ import annotations

import faulthandler
import gc
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node

from robotino_geom_mpc.blas import one_blas_thread
from robotino_geom_mpc.params.files import check_parameter_files
from robotino_geom_mpc.params.specs import ParamError
from robotino_geom_mpc.ros.parameters import NodeStartError
from robotino_geom_mpc.ros.qos import wait_acknowledged
from robotino_geom_mpc.system.signals import STOP, ignore_stop_signals, stop_on_signals

__all__ = ["FINISHED_ACK_WAIT_S", "STOPPED_ACK_WAIT_S", "clock_s", "data_publishers", "monotonic", "params_files",
           "run_node", "run_nodes", "start_rclpy"]

# before exiting, the longest a node waits for its readers to acknowledge what it published: after a run it
# ended itself (the lockstep plant; a recorder can be thousands of samples behind), and when stopped by a
# signal (shorter than the grace before SIGTERM of `system.processes.NodeGroup.stop` and of `ros2 launch`)
FINISHED_ACK_WAIT_S = 30.0
STOPPED_ACK_WAIT_S = 3.0
_EXECUTOR_SHUTDOWN_S = 1.0  # the loop has ended: nothing is spinning, so the executor's shutdown is immediate
_RCLPY_TOPICS = ("/rosout", "/parameter_events")  # every node's own publishers of these, not its data


def params_files(argv: list[str]) -> list[str]:
    """The ``--params-file`` arguments of the ``--ros-args`` parts of `argv`, in order (as rcl reads them)."""
    files, ros, i = [], False, 0
    while i < len(argv):
        if argv[i] == "--ros-args":
            ros = True
        elif argv[i] == "--":
            ros = False
        elif ros and argv[i] == "--params-file" and i + 1 < len(argv):
            i += 1
            files.append(argv[i])
        i += 1
    return files


def start_rclpy(args: list[str] | None = None) -> int | None:
    """What every node process does before its node: SIGINT/SIGTERM set `STOP`, parameter files checked, `rclpy.init`.

    Returns None to go on, or the exit status to end with: 0 when a signal
    came already, 2 when a ``--params-file`` fails
    `params.files.check_parameter_files` (checked before rcl reads it,
    whose YAML errors would be a traceback) or rcl refuses the arguments,
    after one line on stderr naming the file and the key.
    """
    from rclpy.signals import SignalHandlerOptions

    stop = stop_on_signals()
    # SIGUSR1 prints every thread's Python stack on stderr, even with the main thread stuck in C++: what
    # `NodeGroup` sends a node that did not stop before it kills it, so its report says where it hung
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        check_parameter_files(params_files(sys.argv if args is None else args))
        if not stop.is_set():
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            return None
    except (ParamError, _rclpy.RCLError, _rclpy.RCLInvalidROSArgsError, _rclpy.UnknownROSArgsError) as exc:
        message = f"unknown ROS arguments {exc}" if isinstance(exc, _rclpy.UnknownROSArgsError) else str(exc)
        print(f"{_prog()}: error: {(message or type(exc).__name__).splitlines()[0]}", file=sys.stderr)
        ignore_stop_signals()
        return 2
    ignore_stop_signals()
    return 0


def _prog() -> str:
    return Path(sys.argv[0]).name.removesuffix(".py")


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Start (`start_rclpy`), build the node, spin it with the events executor until a signal; returns the status.

    SIGINT and SIGTERM only set a flag (`system.signals.STOP`; in a node process
    from the package's first import on) that is checked before `rclpy.init`
    and by the spin loop (at least every 0.1 s), so no import, callback or
    construction is interrupted half-way; once the loop has ended they are
    ignored, so a second signal during the shutdown cannot kill the process
    either: exit status 0, no traceback. Once the node is built, every
    object there is is moved out of the garbage collector's reach
    (`gc.freeze`): a full collection of the ~70 000 objects rclpy, numpy and
    scipy leave takes ~45 ms, long enough to miss several control periods;
    what the loop allocates later is still collected. A node that ends its
    own run sets a `Future` attribute ``done`` and may set ``exit_status``; a
    node's ``on_stop()``, if it has one, runs once as the loop ends, however it
    ends (the controller's zero command), before the acknowledgement wait.
    A bad parameter file (see `start_rclpy`) or a `NodeStartError` (bad
    parameter) is reported in one line on stderr with exit status 2.
    """
    return run_nodes(lambda: [factory()], args)


def run_nodes(factory: Callable[[], list[Node]], args: list[str] | None = None) -> int:
    """`run_node` for several nodes in one process (a fleet: one node per robot), on one events executor.

    The spin ends on a signal or once every node that has a ``done`` future has it set (none: only a signal);
    the status is the largest ``exit_status``; each node's ``on_stop`` runs, then the acknowledgement wait of
    all their publishers.
    """
    from rclpy.experimental import EventsExecutor

    status = start_rclpy(args)
    if status is not None:
        return status
    nodes: list[Node] = []
    executor, status, stopped = None, 0, False
    try:
        if STOP.is_set():  # a signal during rclpy.init
            return 0
        nodes = factory()
        one_blas_thread()  # also under `ros2 run`: OpenBLAS threads only spin on a node's 3x3-9x9 matrices
        gc.collect()
        gc.freeze()
        executor = EventsExecutor()
        for node in nodes:
            executor.add_node(node)
        dones = [done for done in (getattr(node, "done", None) for node in nodes) if done is not None]
        while not STOP.is_set() and rclpy.ok() and not (dones and all(done.done() for done in dones)):
            executor.spin_once(timeout_sec=0.1)
        status = max((getattr(node, "exit_status", 0) for node in nodes), default=0)
        for node in nodes:
            _stopping(node)
        stopped = True
        # the last samples die with the process: let every reader (a recorder behind the loop) acknowledge them
        finished = bool(dones) and all(done.done() for done in dones)
        wait_acknowledged(nodes[0], [pub for node in nodes for pub in data_publishers(node)],
                          FINISHED_ACK_WAIT_S if finished else STOPPED_ACK_WAIT_S)
    except NodeStartError as exc:
        print(f"{_prog()}: error: {exc}", file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        ignore_stop_signals()
        if not stopped:  # the loop ended by an exception (a failed callback)
            for node in nodes:
                _stopping(node)
        if executor is not None:
            # the executor lets go of the nodes' entities while they are still alive: left to its destructor
            # (after destroy_node and rclpy's shutdown) it finalized QoS events of destroyed publishers, and
            # hung there (CI: trajectory_node stuck in rclpy.event_handler's __exit__ as run_node returned)
            executor.shutdown(timeout_sec=_EXECUTOR_SHUTDOWN_S)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return status


def _stopping(node: Node) -> None:
    """Call the node's ``on_stop()`` if it has one; a failure is reported, not raised."""
    on_stop = getattr(node, "on_stop", None)
    if on_stop is None:
        return
    try:
        on_stop()
    except Exception as exc:  # e.g. the context already shut down: the process ends anyway
        print(f"{_prog()}: {node.get_name()}: on_stop failed: {exc!r}", file=sys.stderr)


def data_publishers(node: Node) -> list:
    """The node's publishers of its data: all but its own /rosout and /parameter_events."""
    return [pub for pub in node.publishers if pub.topic_name not in _RCLPY_TOPICS]


def monotonic() -> float:
    """Steady time in seconds (watchdogs and latency; never the ROS clock)."""
    return time.monotonic()


def clock_s(node: Node) -> float:
    """The node's clock (the ROS clock: /clock under use_sim_time) now, in seconds."""
    return node.get_clock().now().nanoseconds * 1e-9

