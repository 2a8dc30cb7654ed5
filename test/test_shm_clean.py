"""Zombie Fast DDS segments: a SIGKILLed participant's are found and removed, a live participant's are kept.

The truth is Fast DDS itself: a real participant in another process creates
its segment in /dev/shm and holds the lock the kernel drops when it dies.
"""

import os
import signal
import sys
import time
from pathlib import Path

import pytest

from robotino_geom_mpc.system.processes import NodeGroup, NodeProcess
from robotino_geom_mpc.system.shm import SHM_DIR, held_segments, remove_zombie_segments, zombie_segments

pytestmark = [pytest.mark.ros,
              pytest.mark.skipif(not SHM_DIR.is_dir(), reason="Fast DDS keeps its segments in /dev/shm on Linux only")]

_PARTICIPANT = """
import time
import rclpy
rclpy.init()
node = rclpy.create_node("shm_probe")
print("ready", flush=True)
time.sleep(600)
"""


def _start(group: NodeGroup, name: str, timeout_s: float = 60.0) -> tuple[NodeProcess, set[Path]]:
    """A participant process in `group`, once it runs, and the lock files of the segments it made: those it holds
    (`/proc/locks`; other processes, e.g. another pytest worker's, make segments meanwhile).
    """
    node = group.start(name, [], module="shm_probe")
    deadline = time.monotonic() + timeout_s
    while "ready" not in (node.stdout_path.read_text() if node.stdout_path.exists() else ""):
        assert time.monotonic() < deadline, f"the participant did not start:\n{node.stderr_tail()}"
        time.sleep(0.05)
    return node, {SHM_DIR / f"{segment}_el" for segment in held_segments(node.popen.pid)}


def _kill(node: NodeProcess) -> None:
    os.killpg(node.popen.pid, signal.SIGKILL)
    node.popen.wait()


def _gone(locks: set[Path]) -> bool:
    """Whether neither the lock files nor their segments exist."""
    return not any(p.exists() or p.with_name(p.name[: -len("_el")]).exists() for p in locks)


@pytest.fixture
def group(tmp_path):
    """A node group whose nodes can run the probe participant (module ``shm_probe``)."""
    (tmp_path / "shm_probe.py").write_text(_PARTICIPANT)
    return NodeGroup(log_dir=tmp_path / "logs", env={"PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])})


def test_a_killed_participants_segment_is_removed_and_a_live_ones_kept(group):
    since = time.time()
    with group:
        victim, victim_locks = _start(group, "victim")
        survivor, survivor_locks = _start(group, "survivor")
        assert victim_locks and survivor_locks  # each participant made its own segment
        assert not set(zombie_segments(since)) & (victim_locks | survivor_locks)  # both alive: locked

        _kill(victim)
        assert victim_locks <= set(zombie_segments(since))  # the kernel dropped its lock
        assert not set(zombie_segments(since)) & survivor_locks
        # what the group's stop does after a node died, here before the survivor stops
        assert remove_zombie_segments(since) > 0
        assert _gone(victim_locks)
        assert all(p.exists() and p.with_name(p.name[: -len("_el")]).exists() for p in survivor_locks)
    assert _gone(survivor_locks)  # stopped: nothing of it left either


def test_the_group_removes_the_segment_of_a_node_killed_behind_its_back(group):
    with group:
        node, locks = _start(group, "victim")
        assert locks
        _kill(node)
        assert all(p.exists() for p in locks)  # Fast DDS does not clean up after a killed process
    assert _gone(locks)
