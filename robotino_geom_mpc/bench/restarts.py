"""The soak's restart loop: the realtime loop with its controller killed by SIGKILL and started again, many times.

What a killed node can leave behind, counted before the first kill and after the last (once the run's figures are
back where they were, or the survivors have dropped the dead participants: a Fast DDS lease, 20 s, after it;
``restart_settle_s`` says which):

* shared memory: the Fast DDS segment a participant creates in /dev/shm (`system.shm`; a SIGKILL leaves it, the
  supervisor removes it, `remove_zombie_segments`, as `NodeGroup.stop` does) and the shared-memory ports of the
  run's domain (``fastrtps_port<N>``, N in the domain's range of RTPS ports);
* network: the UDP ports bound in the domain's range (``/proc/net/udp``, ``udp6``);
* descriptors: the open file descriptors of every surviving node and of this process (the supervisor);
* and, host-wide, the entries of /dev/shm (other sessions' runs on the machine move this one; the run's own are
  its domain's port files and its segments).

Each figure is also taken after every restart (once the new controller is ready): its least-squares slope over
the restarts (``restart_<figure>_per_restart``) is what a restart leaves behind, with the dead participants'
entries still in the survivors' discovery until their lease ends (a bounded lag, not a leak).

Each killed controller's own segment is found before the kill (the lock file it holds, ``/proc/locks``) and looked
for after it: ``restart_segments_left_by_kill`` counts those a SIGKILL left (Fast DDS's doing, every time),
``restart_segments_left`` those still there after the supervisor's clean.
"""

from __future__ import annotations

import os
import signal
import statistics
import time
from collections.abc import Callable
from pathlib import Path

from robotino_geom_mpc.bench.registry import BenchmarkError
from robotino_geom_mpc.system.shm import SHM_DIR, held_segments, remove_zombie_segments

__all__ = ["LEASE_SETTLE_S", "domain_ports", "open_fds", "per_restart", "restart_loop", "shm_ports",
           "snapshot"]

LEASE_SETTLE_S = 25.0  # after the last kill: Fast DDS's default participant lease (20 s) and a margin
READY_TIMEOUT_S = 120.0  # a restarted controller must log "controller ready" within this
MATCH_S = 0.5  # then runs this long (discovery, a few ticks) before it is killed
SETTLE_POLL_S = 0.5  # after the last kill, the figures are taken again this often until they are back
_PORT_BASE, _DOMAIN_GAIN = 7400, 250  # RTPS well-known ports: PB + DG * domain + offsets (< DG)


def _domain_range() -> range:
    domain = int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    return range(_PORT_BASE + _DOMAIN_GAIN * domain, _PORT_BASE + _DOMAIN_GAIN * (domain + 1))


def domain_ports() -> set[int]:
    """The UDP ports bound on this machine in the current ROS domain's range (``/proc/net/udp``, ``udp6``)."""
    ports, wanted = set(), _domain_range()
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            port = int(line.split()[1].rsplit(":", 1)[1], 16)
            if port in wanted:
                ports.add(port)
    return ports


def shm_ports(directory: Path = SHM_DIR) -> set[str]:
    """The Fast DDS shared-memory port files of the current domain (``fastrtps_port<N>``, their lock files and
    their mutexes, ``sem.fastrtps_port<N>_mutex``).
    """
    wanted = _domain_range()
    names = set()
    for name in os.listdir(directory):
        if name.startswith(("fastrtps_port", "sem.fastrtps_port")):
            digits = name.split("fastrtps_port", 1)[1].split("_", 1)[0]
            if digits.isdigit() and int(digits) in wanted:
                names.add(name)
    return names


def open_fds(pid: int) -> int:
    """The number of open file descriptors of process `pid`."""
    return len(os.listdir(f"/proc/{pid}/fd"))


def snapshot(pids: dict[str, int], segment_pids: list[int], killed: set[str]) -> dict[str, int]:
    """Domain UDP ports, domain shared-memory port files (`shm_ports`), the Fast DDS segments of the run
    (``shm_segments``: those `segment_pids` hold and those of `killed` still in /dev/shm), /dev/shm's entries
    (``shm_entries_host``, host-wide) and each process's descriptors (``fds_<name>``, `pids`).
    """
    held = set().union(*(held_segments(pid) for pid in segment_pids))
    held |= {name for name in killed if (SHM_DIR / name).exists()}
    out = {"udp_ports": len(domain_ports()), "shm_port_files": len(shm_ports()), "shm_segments": len(held),
           "shm_entries_host": len(os.listdir(SHM_DIR))}
    out.update({f"fds_{name}": open_fds(pid) for name, pid in pids.items()})
    return out


def _settled(before: dict[str, int], take: Callable[[], dict[str, int]]) -> tuple[dict[str, int], float]:
    """The snapshot (`take`) once the run's own figures are back to `before`, or the last one after
    `LEASE_SETTLE_S` (the dead participants' lease); and the seconds it took. A leak never settles.
    """
    start = time.monotonic()
    own = [key for key in before if key != "shm_entries_host"]
    while True:
        after = take()
        waited = time.monotonic() - start
        if all(after[key] == before[key] for key in own) or waited >= LEASE_SETTLE_S:
            return after, waited
        time.sleep(SETTLE_POLL_S)


def _wait_ready(node, timeout_s: float) -> None:
    """Wait until `node` logged "controller ready"; `BenchmarkError` if it exits or the time runs out."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if node.popen.poll() is not None:
            raise BenchmarkError(f"restart: the controller exited with {node.popen.returncode}:\n{node.stderr_tail()}")
        if "controller ready" in node.stderr_tail(lines=1000):  # the log, on stderr
            return
        time.sleep(0.05)
    raise BenchmarkError(f"restart: the controller was not ready within {timeout_s:g} s:\n{node.stderr_tail()}")


def per_restart(series: list[dict[str, int]]) -> dict[str, float]:
    """Per figure of `series` (one `snapshot` after each restart): its least-squares slope over the restarts."""
    if len(series) < 2:
        return {}
    return {key: statistics.linear_regression(range(len(series)), [row[key] for row in series]).slope
            for key in series[0]}


def restart_loop(restarts: int, folder: Path, log: Callable[[str], None]) -> dict[str, float]:
    """The realtime loop (paper-circle, no recorder) with its controller SIGKILLed and restarted `restarts` times.

    Returns ``restart_count``, per figure of `snapshot` ``restart_<figure>_before``, ``_after`` (the survivors:
    plant, trajectory, description publisher, and ``bench`` for this process) and ``_per_restart``
    (`per_restart`), ``restart_segments_left_by_kill``
    and ``restart_segments_left`` (see the module docstring), ``restart_loop_s``, the wall time per restart, and
    ``restart_settle_s``, the wait after the last (`_settled`).

    Raises
    ------
    BenchmarkError
        If a node fails or a restarted controller does not come up.
    """
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import NodeGroup, node_arguments

    since = time.time()
    args = node_arguments("paper-circle", default_params_file(), 0.0, lockstep=False)
    with NodeGroup(log_dir=folder / "logs") as group:
        nodes = {name: group.start(name, argv) for name, argv in args.items()}
        controller = nodes["controller_node"]
        _wait_ready(controller, READY_TIMEOUT_S)
        time.sleep(LEASE_SETTLE_S / 5)
        survivors = {name: node.popen.pid for name, node in nodes.items() if name != "controller_node"}
        pids = {**survivors, "bench": os.getpid()}
        killed: set[str] = set()  # the killed controllers' own segments
        before = snapshot(pids, [*survivors.values(), controller.popen.pid], killed)
        left_by_kill, series = 0, []
        start = time.monotonic()
        for k in range(restarts):
            time.sleep(MATCH_S)
            own = held_segments(controller.popen.pid)
            os.killpg(controller.popen.pid, signal.SIGKILL)
            controller.popen.wait()
            left_by_kill += sum((SHM_DIR / name).exists() for name in own)
            killed |= own
            remove_zombie_segments(since)  # the supervisor's part: what the kill left
            for name, node in nodes.items():
                if name != "controller_node" and node.popen.poll() is not None:
                    raise BenchmarkError(f"restart {k + 1}: {name} exited with {node.popen.returncode}:\n"
                                         f"{node.stderr_tail()}")
            group.nodes.remove(controller)  # reaped: its status is the kill's, not a failure
            controller = group.start("controller_node", args["controller_node"])
            _wait_ready(controller, READY_TIMEOUT_S)
            series.append(snapshot(pids, [*survivors.values(), controller.popen.pid], killed))
            if (k + 1) % 20 == 0:
                log(f"restart: {k + 1} of {restarts} kills and restarts; now {series[-1]}")
        wall_s = (time.monotonic() - start) / max(restarts, 1)
        after, settle_s = _settled(before, lambda: snapshot(pids, [*survivors.values(), controller.popen.pid], killed))
        left = sum((SHM_DIR / name).exists() for name in killed)
    out = {"restart_count": restarts, "restart_loop_s": wall_s, "restart_settle_s": settle_s,
           "restart_segments_left_by_kill": left_by_kill, "restart_segments_left": left}
    slopes = per_restart(series)
    for key in before:
        out[f"restart_{key}_before"], out[f"restart_{key}_after"] = before[key], after[key]
        if key in slopes:
            out[f"restart_{key}_per_restart"] = slopes[key]
    log(f"restart: {restarts} kills; before {before}; after {after} ({settle_s:.1f} s after the last); "
        f"segments left by the kills {left_by_kill}, "
        f"after the clean {left}")
    log("restart: left per restart (slope over the restarts): " + ", ".join(
        f"{key} {value:+.4f}" for key, value in slopes.items()))
    return out
