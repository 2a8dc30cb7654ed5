"""SIGINT and SIGTERM in a node process: a stop flag from the package's import to the interpreter's exit.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread is (an
import, `rclpy.init`, a destructor); uncaught, it prints a traceback and the
interpreter kills itself with SIGINT (exit status -2, "process has died" under
``ros2 launch``, which sends SIGINT twice on Ctrl-C and SIGTERM later). So in a
node process SIGINT and SIGTERM only set `STOP`:

* from the first import of the package on (`stop_signals_early`, called by the
  packages' ``__init__`` in a node process only), through the imports,
  `rclpy.init` and the node's construction, all of which `run_node` lets finish;
* until the node's loop has ended; then they are ignored (`ignore_stop_signals`)
  so that the node's destruction, rclpy's shutdown and the interpreter's exit
  (which puts Python-level handlers back to the default action, but leaves
  ignored signals ignored) run to the end with exit status 0.

Imports the standard library only.
"""

from __future__ import annotations

import signal
import sys
import threading

__all__ = ["NODE_MODULES", "STOP", "StopFlag", "ignore_stop_signals", "node_process", "stop_on_signals",
           "stop_signals_early"]

# executable name (setup.py console_scripts) -> module run with `python -m`; here, not in `processes`, because
# `stop_signals_early` runs while the interpreter starts, where every import widens the window it closes
NODE_MODULES: dict[str, str] = {
    "plant_node": "robotino_sim_node.plant_node",
    "controller_node": "robotino_geom_mpc.nodes.controller_node",
    "trajectory_node": "robotino_geom_mpc.nodes.trajectory_node",
    "recorder_node": "robotino_geom_mpc.recording.recorder_node",
    "robot_description_publisher": "robotino_geom_mpc.nodes.robot_description_node",
    "goal_sender": "robotino_geom_mpc.nodes.goal_sender",
    "command_buffer_node": "robotino_geom_mpc.nodes.command_buffer_node",
    "live_view_node": "robotino_geom_mpc.recording.live_view_node",
    "fleet_plant_node": "robotino_sim_node.fleet_plant_node",
    "fleet_controller_node": "robotino_geom_mpc.nodes.fleet_controller_node",
    "fleet_trajectory_node": "robotino_geom_mpc.nodes.fleet_trajectory_node",
}

class StopFlag:
    """A flag a signal handler may set at any moment, with no lock.

    `threading.Event.set` takes the event's non-reentrant lock; a second signal that arrives while the first
    handler is inside it runs the handler again on the same (main) thread, which then waits for the lock it
    holds itself: the node hangs in its stop (seen as "trajectory_node did not stop cleanly", its stack in
    ``Event.set`` under the handler). Setting an attribute is one atomic store under the GIL.
    """

    def __init__(self) -> None:
        self._set = False

    def set(self) -> None:
        """Raise the flag (safe in a signal handler, however nested)."""
        self._set = True

    def is_set(self) -> bool:
        """Whether the flag is raised."""
        return self._set


STOP = StopFlag()
"""Set by SIGINT or SIGTERM once `stop_on_signals` has run."""

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _set_stop(_signum: int, _frame: object) -> None:
    STOP.set()


def stop_on_signals() -> StopFlag:
    """From now on SIGINT and SIGTERM set `STOP` (main thread only; elsewhere nothing changes); returns `STOP`."""
    if threading.current_thread() is threading.main_thread():
        for sig in _SIGNALS:
            signal.signal(sig, _set_stop)
    return STOP


def ignore_stop_signals() -> None:
    """From now on SIGINT and SIGTERM are ignored, up to and through the interpreter's exit."""
    if threading.current_thread() is threading.main_thread():
        for sig in _SIGNALS:
            signal.signal(sig, signal.SIG_IGN)


def node_process(argv: list[str] | None = None, orig_argv: list[str] | None = None) -> bool:
    """Whether this process runs one of the package's nodes (``python -m MODULE`` or its console script)."""
    argv = sys.argv if argv is None else argv
    orig_argv = getattr(sys, "orig_argv", []) if orig_argv is None else orig_argv
    if argv and argv[0].rsplit("/", 1)[-1] in NODE_MODULES:
        return True
    if "-m" in orig_argv[:-1]:
        return orig_argv[orig_argv.index("-m") + 1] in NODE_MODULES.values()
    return False


def stop_signals_early() -> None:
    """`stop_on_signals` if this is a node process (`node_process`), else nothing: for the packages' ``__init__``."""
    if node_process():
        stop_on_signals()
