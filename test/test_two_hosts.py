"""The loop across two hosts: the plant in one Linux network namespace, trajectory, controller and recorder in another.

The namespaces are joined by a veth pair (10.77.0.1/24, 10.77.0.2/24); DDS runs over UDP only
(config/fastdds_udp.xml: no shared memory, which would bypass the network), discovery reaches the subnet
with the other host as a static peer (``ROS_STATIC_PEERS``). The recording, read back from the bag, must
equal the offline loop of `simulate` to 1e-6 in lockstep, and in realtime the robot must track paper-circle.
The veth's byte counters show the loop's traffic crossed it. Needs root (``ip netns``); skipped otherwise.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import time
from dataclasses import dataclass

import numpy as np
import pytest

from robotino_geom_mpc.bench.dds import read_timing_report
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import config_file, default_params_file
from robotino_geom_mpc.recording.report import run_data_from_bag
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.system.processes import NodeGroup, node_arguments
from robotino_geom_mpc.offline.simulation import run_scenario

pytestmark = [pytest.mark.ros, pytest.mark.skipif(os.geteuid() != 0 or shutil.which("ip") is None,
                                                  reason="needs root and iproute2 (ip netns)")]

ADDRESSES = ("10.77.0.1", "10.77.0.2")  # the plant's host, the controller's
LINGER_S = 0.5  # after the plant's last tick: the controller's last answer reaches the recorder
# realtime paper-circle over the veth: RMS position error after settling (measured 8.1e-6 m, max 1.5e-5 m,
# on 2 cores, none of 400 ticks missed); 0.1 mm leaves a margin of 12 for scheduling jitter
REALTIME_RMS_LIMIT_M = 1e-4
# the precision claim holds for a loop that keeps its deadlines: with more ticks missed (commands later
# than the next odometry, a host overloaded by other processes: 94 of 241 at load 12 on 2 cores gave
# 9 mm on localhost too) the test is skipped with the plant's figures
REALTIME_MISSED_LIMIT = 0.05


@dataclass
class Hosts:
    """Two network namespaces joined by a veth pair: names, veth ends, addresses."""

    namespaces: tuple[str, str]
    links: tuple[str, str]

    def prefix(self, host: int) -> tuple[str, ...]:
        """The command that runs a node on `host` (0: the plant's, 1: the controller's)."""
        return ("ip", "netns", "exec", self.namespaces[host])

    def received_bytes(self, host: int) -> int:
        """Bytes received on `host`'s end of the veth."""
        out = subprocess.run(["ip", "-n", self.namespaces[host], "-j", "-s", "link", "show", self.links[host]],
                             check=True, capture_output=True, text=True).stdout
        return int(json.loads(out)[0]["stats64"]["rx"]["bytes"])


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@pytest.fixture
def hosts():
    """Two fresh network namespaces (unique names) with a veth pair; always deleted (and the veth with them)."""
    tag = secrets.token_hex(4)
    namespaces, links = (f"rgm_plant_{tag}", f"rgm_ctrl_{tag}"), (f"rgmp{tag}", f"rgmc{tag}")
    made = []
    try:
        for name in namespaces:
            try:
                _ip("netns", "add", name)
            except subprocess.CalledProcessError as exc:  # e.g. a container without CAP_SYS_ADMIN
                pytest.skip(f"cannot create a network namespace: {exc.stderr.strip()}")
            made.append(name)
        _ip("link", "add", links[0], "type", "veth", "peer", "name", links[1])
        for name, link, address in zip(namespaces, links, ADDRESSES):
            _ip("link", "set", link, "netns", name)
            _ip("-n", name, "addr", "add", f"{address}/24", "dev", link)
            _ip("-n", name, "link", "set", link, "up")
            _ip("-n", name, "link", "set", "lo", "up")
        yield Hosts(namespaces, links)
    finally:
        subprocess.run(["ip", "link", "del", links[0]], capture_output=True)  # if it stayed in the root namespace
        for name in made:
            subprocess.run(["ip", "netns", "del", name], capture_output=True)


def _run(hosts: Hosts, tmp_path, scenario: str, duration_s: float, lockstep: bool):
    """Run the loop across the two hosts, recorded on the controller's.

    Returns the run read from the bag, the bytes received on the plant's end of the veth meanwhile, and the
    plant's timing report (`bench.dds.read_timing_report`).
    """
    params = default_params_file()
    bag = tmp_path / "bag"
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_STATIC_PEERS": ";".join(ADDRESSES),
           "FASTRTPS_DEFAULT_PROFILES_FILE": str(config_file("fastdds_udp.xml"))}
    report = tmp_path / "timing.json"
    args = node_arguments(scenario, params, duration_s, lockstep, bag=bag,
                          overrides={"plant_node": {"timing_report": str(report)}}, environ={**os.environ, **env})
    before = hosts.received_bytes(0)
    with NodeGroup(tmp_path / "plant_host", env, hosts.prefix(0)) as plant_host, \
            NodeGroup(tmp_path / "controller_host", env, hosts.prefix(1)) as controller_host:
        others = [controller_host.start(name, argv) for name, argv in args.items() if name != "plant_node"]
        plant = plant_host.start("plant_node", args["plant_node"])
        deadline = time.monotonic() + 60.0 + 20.0 * duration_s
        while not plant_host.wait(plant, 0.2):
            controller_host.check()
            assert time.monotonic() < deadline, f"the run did not end:\n{plant.stderr_tail()}"
        assert plant.popen.returncode == 0, plant.stderr_tail()
        time.sleep(LINGER_S)
        for node in others:  # SIGINT: the recorder closes the bag
            assert controller_host.stop_node(node) == 0, node.stderr_tail()
    crossed = hosts.received_bytes(0) - before
    timing = read_timing_report(report, "lockstep" if lockstep else "realtime")
    return run_data_from_bag(bag, params, scenario), crossed, timing


def test_lockstep_across_two_network_namespaces_equals_simulate(hosts, tmp_path):
    duration_s = 3.0
    robot, control = load_params()
    dds, crossed, _ = _run(hosts, tmp_path, "paper-circle", duration_s, lockstep=True)
    offline = run_scenario("paper-circle", robot, control, duration_s=duration_s)
    assert dds.n == offline.n == round(duration_s / control.period_s)
    for name in ("t", "pose", "reference", "currents", "voltages"):
        np.testing.assert_allclose(getattr(dds, name), getattr(offline, name), rtol=1e-6, atol=1e-9, err_msg=name)
    # every tick's three voltages (a Float64MultiArray, > 100 bytes) crossed the veth to the plant's host
    assert crossed > 100 * offline.n


def test_realtime_across_two_network_namespaces_tracks_paper_circle(hosts, tmp_path):
    duration_s = 4.0
    dds, crossed, timing = _run(hosts, tmp_path, "paper-circle", duration_s, lockstep=False)
    # the loop ran across the veth: the recording holds a second of it at least (in realtime the plant does
    # not wait for the others), most ticks were answered, each tick's commands crossed
    assert dds.n >= round(1.0 / dds.control_period_s)
    assert timing["answered"] > timing["missed"] and timing["latency_ms"]["median"] < 1e3 * dds.control_period_s
    assert crossed > 100 * dds.n
    missed = timing["missed"] / (timing["answered"] + timing["missed"])
    if missed > REALTIME_MISSED_LIMIT:
        pytest.skip(f"host overloaded: {timing['missed']} of {timing['answered'] + timing['missed']} ticks missed; "
                    "the tracking precision needs a loop that keeps its deadlines")
    rms = compute_metrics(dds)["rms_position_error_m"]
    assert rms < REALTIME_RMS_LIMIT_M, rms
