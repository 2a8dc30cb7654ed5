"""`system.signals`' stop handler under a second signal that arrives while the first handler runs.

``ros2 launch`` sends SIGINT twice on Ctrl-C. The stop flag used to be a `threading.Event`, whose ``set`` takes a
non-reentrant lock: a second SIGINT handled inside the first handler's ``set`` waited for the lock its own thread
held, and the node hung in its stop. A child process installs the real handlers (`stop_on_signals`) and, by a
trace function, raises SIGINT again at each of the first lines the handler and the flag's ``set`` execute (before
the flag is set); ``signal.raise_signal`` runs the handler before it returns, so the second handler runs nested
inside the first. With `StopFlag` the child ends at once with the flag set; with an Event in its place (the old
flag) the same child hangs in ``Event.set``, which shows the second signal reaches the lock.
"""

import subprocess
import sys

import pytest

pytestmark = pytest.mark.ros  # starts a (plain Python) child process

HANG_TIMEOUT_S = 60.0  # only stops a hang; the child ends in well under a second
EVENT_WATCHDOG_S = 3.0  # the Event child hangs at once: its stack is dumped (faulthandler) this long after

CHILD = r"""
import faulthandler, signal, sys, threading
from robotino_geom_mpc.system import signals

if sys.argv[1] == "event":
    signals.STOP = threading.Event()  # the flag StopFlag replaced, in the real handler's place
signals.stop_on_signals()
handler, flag_set = signals._set_stop.__code__, type(signals.STOP).set.__code__
state = {"raised": 0, "set_after_raise": []}


def local(frame, event, arg):
    if event == "line" and state["raised"] < 4:
        state["raised"] += 1
        signal.raise_signal(signal.SIGINT)  # another SIGINT while a handler runs; handled before it returns
        state["set_after_raise"].append(signals.STOP.is_set())
    return local


def tracer(frame, event, arg):
    return local if frame.f_code in (handler, flag_set) else None


faulthandler.dump_traceback_later(float(sys.argv[2]), exit=True)
sys.settrace(tracer)
signal.raise_signal(signal.SIGINT)
sys.settrace(None)
faulthandler.cancel_dump_traceback_later()
print(signals.STOP.is_set(), *state["set_after_raise"])
"""


def _child(flag: str, watchdog_s: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", CHILD, flag, str(watchdog_s)], capture_output=True, text=True,
                          timeout=HANG_TIMEOUT_S, stdin=subprocess.DEVNULL)


def test_a_second_sigint_inside_the_handler_neither_hangs_nor_loses_the_stop():
    done = _child("stop_flag", HANG_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    # one SIGINT raised again at the handler's line (the call of STOP.set), one inside StopFlag.set; the first
    # one's handler ran nested in the first handler: the flag is up before the first handler's own set ran
    assert done.stdout.split() == ["True", "True", "True"]


def test_the_same_nesting_hangs_the_event_the_flag_replaced():
    done = _child("event", EVENT_WATCHDOG_S)
    # faulthandler's exit after the watchdog: the main thread waits for the lock inside Event.set
    assert done.returncode != 0 and done.stdout == ""
    stack = done.stderr
    assert "Timeout" in stack and "threading.py" in stack and "in set" in stack, stack
