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

from robotino_geom_mpc.ros.processes import NodeGroup
from robotino_geom_mpc.ros.shm import SHM_DIR, remove_zombie_segments, zombie_segments

pytestmark = pytest.mark.skipif(not SHM_DIR.is_dir(), reason="Fast DDS keeps its segments in /dev/shm on Linux only")

_PARTICIPANT = """
import time
import rclpy
rclpy.init()
node = rclpy.create_node("shm_probe")
print("ready", flush=True)
time.sleep(600)
"""


def _segment_locks() -> set[Path]:
    return {p for p in SHM_DIR.glob("fastrtps_*_el") if not p.name.startswith("fastrtps_port")}


def _wait_ready(log: Path, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while "ready" not in (log.read_text() if log.exists() else ""):
        assert time.monotonic() < deadline, "the participant did not start"
        time.sleep(0.05)


def test_a_killed_participants_segment_is_removed_and_a_live_ones_kept(tmp_path):
    (tmp_path / "shm_probe.py").write_text(_PARTICIPANT)
    since = time.time()
    before = _segment_locks()
    group = NodeGroup(log_dir=tmp_path / "logs", env={"PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])})
    with group:
        victim = group.start("victim", [], module="shm_probe")
        _wait_ready(victim.stdout_path)
        victim_locks = _segment_locks() - before
        survivor = group.start("survivor", [], module="shm_probe")
        _wait_ready(survivor.stdout_path)
        survivor_locks = _segment_locks() - before - victim_locks
        assert victim_locks and survivor_locks  # each participant made its own segment
        assert not set(zombie_segments(since)) & (victim_locks | survivor_locks)  # both alive: locked

        os.killpg(victim.popen.pid, signal.SIGKILL)
        victim.popen.wait()
        assert victim_locks <= set(zombie_segments(since))  # the kernel dropped its lock
        assert not set(zombie_segments(since)) & survivor_locks
        # what the group's stop does after a node died, here before the survivor stops
        assert remove_zombie_segments(since) > 0
        assert not any(p.exists() or p.with_name(p.name[:-3]).exists() for p in victim_locks)
        assert all(p.exists() and p.with_name(p.name[:-3]).exists() for p in survivor_locks)
    assert not any(p.exists() for p in survivor_locks)  # stopped: nothing of it left either


def test_the_group_removes_the_segment_of_a_node_killed_behind_its_back(tmp_path):
    (tmp_path / "shm_probe.py").write_text(_PARTICIPANT)
    before = _segment_locks()
    group = NodeGroup(log_dir=tmp_path / "logs", env={"PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])})
    with group:
        node = group.start("victim", [], module="shm_probe")
        _wait_ready(node.stdout_path)
        locks = _segment_locks() - before
        assert locks
        os.killpg(node.popen.pid, signal.SIGKILL)
        node.popen.wait()
        assert all(p.exists() for p in locks)  # Fast DDS does not clean up after a killed process
    assert not any(p.exists() or p.with_name(p.name[:-3]).exists() for p in locks)
