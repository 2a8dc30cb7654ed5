"""Test session setup: an isolated DDS domain and the ament index of the venv.

Set before anything imports rclpy: each session gets its own random
ROS_DOMAIN_ID, discovery stays on localhost, and every participant (the
tests' own and the nodes') gets the Fast DDS profile `run` gives its nodes
(`processes.dds_environment`). At the end, the Fast DDS segments that the
session's killed processes left in /dev/shm are removed.
"""

import os
import random
import sys
import time

import pytest

os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")

from robotino_geom_mpc.system.processes import dds_environment  # noqa: E402  (after the variables it reads)

os.environ.update(dds_environment(os.environ))

_SESSION_START = time.time()


def pytest_sessionfinish(session, exitstatus):
    """Remove the zombie Fast DDS segments of this session (the tests SIGKILL nodes on purpose)."""
    from robotino_geom_mpc.system.shm import remove_zombie_segments

    remove_zombie_segments(_SESSION_START)


@pytest.fixture
def procs(tmp_path):
    """Child processes of one test (`recording_helpers.Processes`), ended when it ends."""
    from recording_helpers import Processes

    processes = Processes(tmp_path)
    yield processes
    processes.close()
