"""Which processes `system.signals.stop_signals_early` acts in, in-process (moved from the process module
test_fault_signals: no process started).
"""

import pytest

pytestmark = pytest.mark.unit


def test_node_processes_are_recognised_from_their_command_line():
    """`stop_signals_early` acts in a node process only: ``python -m MODULE`` or the console script."""
    from robotino_geom_mpc.system import processes, signals

    assert signals.NODE_MODULES == processes.NODE_MODULES  # two copies until processes imports it from signals
    for executable, module in signals.NODE_MODULES.items():
        assert signals.node_process(["-m"], ["/venv/bin/python", "-u", "-m", module, "--ros-args"])
        assert signals.node_process([f"/opt/ros/lib/robotino_geom_mpc/{executable}"], [])
    assert not signals.node_process(["-m"], ["/venv/bin/python", "-m", "robotino_geom_mpc", "run"])
    assert not signals.node_process(["/venv/bin/pytest", "-q"], ["/venv/bin/python", "/venv/bin/pytest", "-q"])
    assert not signals.node_process(["-c"], ["/venv/bin/python", "-c", "import robotino_geom_mpc"])
