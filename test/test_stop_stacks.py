"""A node that does not stop is killed, but first prints where it is stuck.

`NodeGroup` sends SIGUSR1 before SIGKILL, and every node process (`ros.spin.start_rclpy`) answers it with all
its threads' stacks on stderr.
"""

import signal
import time

import pytest

from robotino_geom_mpc.system.processes import NodeGroup

pytestmark = pytest.mark.ros

STUCK_NODE = '''
import time
from robotino_geom_mpc.ros.spin import start_rclpy
from robotino_geom_mpc.system.signals import ignore_stop_signals


def stuck_in_its_stop():
    while True:
        time.sleep(0.05)


if start_rclpy() is None:
    ignore_stop_signals()  # as a node whose stop hangs: SIGINT and SIGTERM do nothing any more
    print("ready", flush=True)
    stuck_in_its_stop()
'''


def test_a_node_that_hangs_in_its_stop_says_where_before_it_is_killed(tmp_path):
    (tmp_path / "stuck_node.py").write_text(STUCK_NODE)
    with NodeGroup(log_dir=tmp_path / "logs", env={"PYTHONPATH": str(tmp_path)}) as group:
        node = group.start("stuck_node", ["--ros-args"], module="stuck_node")
        deadline = time.monotonic() + 60.0
        while "ready" not in node.stdout_path.read_text() and time.monotonic() < deadline:
            assert node.popen.poll() is None, node.stderr_tail()
            time.sleep(0.05)
        assert group.stop_node(node, grace_s=0.5) == -signal.SIGKILL
    stacks = node.stderr_path.read_text()
    assert "Current thread" in stacks  # faulthandler's dump of every thread
    assert 'stuck_node.py", line 9 in stuck_in_its_stop' in stacks  # the frame it hangs in
