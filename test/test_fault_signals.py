"""Two signals 50-100 ms apart (Ctrl-C under ``ros2 launch`` sends SIGINT twice, then SIGTERM) end every node cleanly.

The four nodes run as one realtime system of real processes (`NodeGroup`), as ``ros2 launch`` starts them,
and all get the pair at once: during start-up (imports, rclpy.init, the node's construction) at fixed times
after the start, and while the system runs (every node answers its parameter service), where the second
signal falls into the shutdown. Every node must exit with status 0 and print no traceback.

"After the start" counts from the package's start in the process: its handlers visible in /proc/PID/status
(`system.signals.stop_signals_early`, the package's first import), or at the latest numpy mapped in
/proc/PID/maps (each node's first heavy import, so a missing or late handler still fails). Before that the
interpreter itself is starting (site, .pth files: ~50 ms on an idle machine, far longer under load) and
no code of the package can run: a SIGINT there kills any Python program.
"""

import contextlib
import signal
import time
from pathlib import Path

import pytest
from harness import Harness

from robotino_geom_mpc.params.presets import preset_file
from robotino_geom_mpc.system.processes import NodeGroup, ros_args

pytestmark = pytest.mark.ros

NODES = {  # executable -> node name
    "plant_node": "robotino_plant",
    "controller_node": "robotino_controller",
    "trajectory_node": "robotino_trajectory",
    "recorder_node": "recorder",
}
EXIT_TIMEOUT_S = 60.0  # a hang fails the test; a clean exit takes well under a second after the node is up


def _package_started(pid: int) -> bool:
    """Whether the process catches or ignores SIGTERM (Python does neither by itself) or has numpy loaded."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        maps = Path(f"/proc/{pid}/maps").read_text()
    except OSError:  # already gone
        return True
    masks = [int(line.split()[1], 16) for line in status.splitlines() if line.startswith(("SigCgt:", "SigIgn:"))]
    return any(m & (1 << (signal.SIGTERM - 1)) for m in masks) or "_multiarray_umath" in maps


def _start_system(group: NodeGroup, folder: Path) -> dict:
    params = preset_file("robotino3")
    return {
        "plant_node": group.start("plant_node", ros_args(params)),
        "controller_node": group.start("controller_node", ros_args(params)),
        "trajectory_node": group.start("trajectory_node", ros_args(params)),
        "recorder_node": group.start("recorder_node", ros_args(params, {"output": str(folder / "bag")})),
    }


@pytest.mark.parametrize(
    "moment, second, gap_s",
    [
        (0.2, signal.SIGINT, 0.05),
        (0.5, signal.SIGINT, 0.075),
        (1.0, signal.SIGINT, 0.1),
        (2.0, signal.SIGINT, 0.05),
        ("running", signal.SIGINT, 0.075),
        (1.0, signal.SIGTERM, 0.075),
        ("running", signal.SIGTERM, 0.05),
    ],
)
def test_a_second_signal_never_kills_a_node(tmp_path, moment, second, gap_s):
    with contextlib.ExitStack() as stack:
        group = stack.enter_context(NodeGroup(log_dir=tmp_path / "logs"))
        start = time.monotonic()
        nodes = _start_system(group, tmp_path)
        if moment == "running":
            h = stack.enter_context(Harness("fault_signals_probe"))
            for name in NODES.values():  # answering its parameter service: the node is built and spinning
                h.get_parameters(name, ["use_sim_time"], timeout_s=EXIT_TIMEOUT_S)
        else:
            while not all(_package_started(n.popen.pid) for n in nodes.values()):
                time.sleep(0.005)
            time.sleep(max(0.0, start + moment - time.monotonic()))
        for node in nodes.values():
            node.popen.send_signal(signal.SIGINT)
        time.sleep(gap_s)
        for node in nodes.values():
            if node.popen.poll() is None:
                node.popen.send_signal(second)
        statuses = {}
        for name, node in nodes.items():
            try:
                statuses[name] = node.popen.wait(timeout=EXIT_TIMEOUT_S)
            except Exception:  # a hang: the group's stop ends it; reported below
                statuses[name] = "hang"
        for name, node in nodes.items():
            output = node.stdout_path.read_text() + node.stderr_path.read_text()
            assert statuses[name] == 0 and "Traceback" not in output and "Fatal Python" not in output, (
                f"{name}: status {statuses[name]}\n{node.stderr_tail()}")
