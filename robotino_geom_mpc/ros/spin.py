"""The main loop every node runs: rclpy init, the events executor, quiet exits on signals and start errors."""

from __future__ import annotations

import gc
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from robotino_geom_mpc.ros.parameters import NodeStartError

__all__ = ["monotonic", "run_node"]


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Init rclpy, build the node, spin it with the events executor, exit quietly on SIGINT/SIGTERM.

    SIGINT and SIGTERM only set a flag the spin loop checks (at least every
    0.1 s), so no callback is interrupted half-way and no traceback is
    printed. Once the node is built, every object there is is moved out of
    the garbage collector's reach (`gc.freeze`): a full collection of the
    ~70 000 objects rclpy, numpy and scipy leave takes ~45 ms, long enough
    to miss several control periods; what the loop allocates later is
    still collected. A node that ends its own run sets a `Future` attribute ``done``
    and may set ``exit_status``. A `NodeStartError` (bad parameter) is
    reported in one line on stderr with exit status 2. Returns the exit status.
    """
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    stop = threading.Event()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = None
    status = 0
    try:
        node = factory()
        gc.collect()
        gc.freeze()
        executor = EventsExecutor()
        executor.add_node(node)
        done = getattr(node, "done", None)
        while not stop.is_set() and rclpy.ok() and not (done is not None and done.done()):
            executor.spin_once(timeout_sec=0.1)
        status = getattr(node, "exit_status", 0)
        if done is not None and done.done():  # a finished run: let the last samples reach every reader
            for pub in node.publishers:
                pub.wait_for_all_acked(Duration(seconds=1.0))
    except NodeStartError as exc:
        print(f"{Path(sys.argv[0]).name.removesuffix('.py')}: error: {exc}", file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return status


def monotonic() -> float:
    """Steady time in seconds (watchdogs and latency; never the ROS clock)."""
    return time.monotonic()
