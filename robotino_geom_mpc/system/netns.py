"""Two hosts on one machine: Linux network namespaces joined by a veth pair, and a run of the nodes across them.

The plant runs on host 0 (the robot's), every other node on host 1 (the off-board one). The namespaces are
joined by a veth pair (`HOST_ADDRESSES`, a /24); DDS runs over UDP only (config/fastdds_udp.xml: no shared
memory, which would bypass the network, as the namespaces share one /dev/shm), discovery reaches the subnet
with both hosts as static peers (``ROS_STATIC_PEERS``). The veth's byte counters tell what crossed it. Needs
root and iproute2 (``ip netns``); `netns_unavailable` says why not. Used by test_two_hosts.py,
test_fleet_hosts.py (a fleet: `run_across_hosts` with the fleet plant) and the ``networked`` benchmark.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.system.processes import NodeFailed, NodeGroup

__all__ = ["HOST_ADDRESSES", "LINGER_S", "Hosts", "NetnsUnavailable", "netns_unavailable", "run_across_hosts",
           "two_hosts"]

HOST_ADDRESSES = ("10.77.0.1", "10.77.0.2")  # the plant's host, the controller's
LINGER_S = 0.5  # after the plant's last tick: the controller's last answer reaches the recorder
PLANT_HOST, OTHERS_HOST = 0, 1


class NetnsUnavailable(RobotinoError, RuntimeError):
    """Network namespaces cannot be made here (not root, no iproute2, or the kernel refused); the message says why."""


@dataclass(frozen=True)
class Hosts:
    """Two network namespaces joined by a veth pair: names, veth ends, addresses (host 0: the plant's)."""

    namespaces: tuple[str, str]
    links: tuple[str, str]
    addresses: tuple[str, str] = HOST_ADDRESSES

    def prefix(self, host: int) -> tuple[str, ...]:
        """The command that runs a node on `host` (0: the plant's, 1: the others')."""
        return ("ip", "netns", "exec", self.namespaces[host])

    def received_bytes(self, host: int) -> int:
        """Bytes received on `host`'s end of the veth (its ``rx`` counter)."""
        out = subprocess.run(["ip", "-n", self.namespaces[host], "-j", "-s", "link", "show", self.links[host]],
                             check=True, capture_output=True, text=True).stdout
        return int(json.loads(out)[0]["stats64"]["rx"]["bytes"])

    def dds_environment(self) -> dict[str, str]:
        """The nodes' DDS settings on either host: UDP only, subnet discovery, both hosts as static peers."""
        from robotino_geom_mpc.params.presets import config_file

        return {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_STATIC_PEERS": ";".join(self.addresses),
                "FASTRTPS_DEFAULT_PROFILES_FILE": str(config_file("fastdds_udp.xml"))}


def netns_unavailable() -> str | None:
    """Why `two_hosts` cannot run here (not root, no ``ip``), or None when it may (the kernel may still refuse)."""
    if os.geteuid() != 0:
        return "network namespaces need root (ip netns)"
    if shutil.which("ip") is None:
        return "network namespaces need iproute2 (no `ip` on PATH)"
    return None


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@contextmanager
def two_hosts(addresses: tuple[str, str] = HOST_ADDRESSES) -> Iterator[Hosts]:
    """Two fresh network namespaces (unique names) joined by a veth pair with `addresses` (/24), loopback up;
    always deleted on exit (and the veth with them).

    Raises
    ------
    NetnsUnavailable
        If `netns_unavailable` gives a reason, or ``ip netns add`` fails (e.g. a container without
        CAP_SYS_ADMIN).
    """
    reason = netns_unavailable()
    if reason is not None:
        raise NetnsUnavailable(reason)
    tag = secrets.token_hex(4)
    namespaces, links = (f"rgm_plant_{tag}", f"rgm_ctrl_{tag}"), (f"rgmp{tag}", f"rgmc{tag}")
    made = []
    try:
        for name in namespaces:
            try:
                _ip("netns", "add", name)
            except subprocess.CalledProcessError as exc:
                raise NetnsUnavailable(f"cannot create a network namespace: {exc.stderr.strip()}") from None
            made.append(name)
        _ip("link", "add", links[0], "type", "veth", "peer", "name", links[1])
        for name, link, address in zip(namespaces, links, addresses):
            _ip("link", "set", link, "netns", name)
            _ip("-n", name, "addr", "add", f"{address}/24", "dev", link)
            _ip("-n", name, "link", "set", link, "up")
            _ip("-n", name, "link", "set", "lo", "up")
        yield Hosts(namespaces, links, addresses)
    finally:
        subprocess.run(["ip", "link", "del", links[0]], capture_output=True)  # if it stayed in the root namespace
        for name in made:
            subprocess.run(["ip", "netns", "del", name], capture_output=True)


def run_across_hosts(hosts: Hosts, node_args: dict[str, list[str]], log_dir: str | os.PathLike,
                     timeout_s: float, env: Mapping[str, str] | None = None,
                     plant: str = "plant_node") -> tuple[int, int]:
    """Run a run's nodes (`processes.node_arguments`, or a fleet's: `processes.fleet_arguments` with `plant`
    ``fleet_plant_node``) with the plant (executable `plant`) on host 0 and the others on host 1.

    The others start first, then the plant, which ends the run; `LINGER_S` after its exit the others get
    SIGINT, the recorder last (it closes its bag). Each host's node logs go to `log_dir`/plant_host and
    `log_dir`/controller_host. `env` (default `Hosts.dds_environment`) is the nodes' extra environment; it
    should also be the ``environ`` given to `node_arguments`. Returns the bytes received on each host's end
    of the veth meanwhile (host 0's, host 1's).

    Raises
    ------
    NodeFailed
        If a node exits with a non-zero status (the plant at its end, another at its SIGINT) or the plant
        does not end within `timeout_s`; the message quotes the node's stderr.
    """
    env = dict(hosts.dds_environment() if env is None else env)
    log_dir = Path(log_dir)
    before = [hosts.received_bytes(h) for h in (PLANT_HOST, OTHERS_HOST)]
    order = sorted((n for n in node_args if n != plant), key=lambda n: n == "recorder_node")
    with NodeGroup(log_dir / "plant_host", env, hosts.prefix(PLANT_HOST)) as plant_host, \
            NodeGroup(log_dir / "controller_host", env, hosts.prefix(OTHERS_HOST)) as others_host:
        others = [others_host.start(name, node_args[name]) for name in order]
        plant_node = plant_host.start(plant, node_args[plant])
        deadline = time.monotonic() + timeout_s
        while not plant_host.wait(plant_node, 0.2):
            others_host.check()
            if time.monotonic() > deadline:
                raise NodeFailed(f"the run did not end within {timeout_s:g} s:\n{plant_node.stderr_tail()}")
        if plant_node.popen.returncode != 0:
            raise NodeFailed(f"{plant} exited with status {plant_node.popen.returncode}:\n"
                             f"{plant_node.stderr_tail()}")
        time.sleep(LINGER_S)
        for node in others:  # SIGINT, the recorder last: it closes the bag with every other node's last message
            status = others_host.stop_node(node)
            if status != 0:
                raise NodeFailed(f"{node.name} exited with status {status} on SIGINT:\n{node.stderr_tail()}")
    after = [hosts.received_bytes(h) for h in (PLANT_HOST, OTHERS_HOST)]
    return after[0] - before[0], after[1] - before[1]
