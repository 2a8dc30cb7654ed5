"""Test session setup: an isolated DDS domain, the ament index of the venv, the tiers, Hypothesis in CI.

Set before anything imports rclpy: each session gets its own random ROS_DOMAIN_ID (each pytest-xdist worker of a
run its own, neighbours of a base drawn from the run's id), discovery stays on localhost, and every participant
(the tests' own and the nodes') gets the Fast DDS profile `run` gives its nodes (`processes.dds_environment`); BLAS
runs on one thread, as in the nodes and the command line. At the end, the Fast DDS segments that the session's
killed processes left in /dev/shm are removed.

Every test is in one tier, marked in its file (setup.cfg lists the markers): ``unit`` (in-process, no
child process, no DDS: `make unit`) or ``ros`` (starts processes: nodes over DDS, the CLI, worker pools);
``slow`` marks the long ones besides. Under CI=true Hypothesis runs derandomized (the same examples each run).
"""

import os
import random
import sys
import time

import pytest
from hypothesis import settings

from robotino_geom_mpc.blas import one_blas_thread

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI", "").lower() == "true":
    settings.load_profile("ci")



def _domain_id() -> int:
    """A random domain in 1..101; under pytest-xdist, the run's base plus the worker's number (no two alike)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None:
        return random.SystemRandom().randint(1, 101)
    count = int(os.environ["PYTEST_XDIST_WORKER_COUNT"])
    base = int(os.environ["PYTEST_XDIST_TESTRUNUID"], 16) % (101 // count) * count + 1
    return base + int(worker.removeprefix("gw"))


os.environ["ROS_DOMAIN_ID"] = str(_domain_id())
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the command line and the nodes run: small matrices
one_blas_thread()  # numpy may be loaded already (a plugin)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")

from robotino_geom_mpc.system.processes import dds_environment  # noqa: E402  (after the variables it reads)

os.environ.update(dds_environment(os.environ))

_SESSION_START = time.time()


@pytest.fixture
def hosts():
    """Two fresh network namespaces joined by a veth pair (`system.netns.two_hosts`), always deleted: the hosts of
    test_two_hosts and test_fleet_hosts; the test is skipped where the kernel refuses them (e.g. no CAP_SYS_ADMIN).
    """
    from robotino_geom_mpc.system.netns import NetnsUnavailable, two_hosts

    try:
        with two_hosts() as made:
            yield made
    except NetnsUnavailable as exc:
        pytest.skip(str(exc))


def pytest_sessionfinish(session, exitstatus):
    """Remove the zombie Fast DDS segments of this session (the tests SIGKILL nodes on purpose)."""
    from robotino_geom_mpc.system.shm import remove_zombie_segments

    remove_zombie_segments(_SESSION_START)


TIERS = ("unit", "ros")


def pytest_collection_modifyitems(config, items):
    """Refuse a test without exactly one tier (a file's ``pytestmark``, or the test's own mark); run the files
    with a ``slow`` test first, each file's tests together (its module fixtures once): under pytest-xdist the long
    tests then start early, and the short ones fill the workers' ends.
    """
    untiered = [item.nodeid for item in items if sum(item.get_closest_marker(t) is not None for t in TIERS) != 1]
    if untiered:
        raise pytest.UsageError(f"tests need exactly one of the marks {TIERS}: {untiered[:5]} ({len(untiered)})")
    slow_files = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow_files)  # stable: the order within each group stays


@pytest.fixture
def procs(tmp_path):
    """Child processes of one test (`recording_helpers.Processes`), ended when it ends."""
    from recording_helpers import Processes

    processes = Processes(tmp_path)
    yield processes
    processes.close()


PAPER_CIRCLE_RUN_S = 3.0  # `paper_circle_run`'s --duration


@pytest.fixture(scope="session")
def paper_circle_run(tmp_path_factory):
    """One ``robotino-geom-mpc run --scenario paper-circle --duration 3`` (lockstep, recorded) for the tests that
    read what a run leaves (its metrics, figures, logs, bag): its output folder, the finished process, --duration.
    """
    import subprocess

    out = tmp_path_factory.mktemp("paper_circle_run") / "run"
    proc = subprocess.run([sys.executable, "-m", "robotino_geom_mpc", "run", "--scenario", "paper-circle",
                           "--duration", f"{PAPER_CIRCLE_RUN_S:g}", "--out", str(out)],
                          capture_output=True, text=True, timeout=600, env=os.environ.copy())
    return out, proc, PAPER_CIRCLE_RUN_S
