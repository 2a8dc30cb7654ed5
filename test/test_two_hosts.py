"""The loop across two hosts: the plant in one Linux network namespace, trajectory, controller and recorder in another.

The namespaces are joined by a veth pair (10.77.0.1/24, 10.77.0.2/24); DDS runs over UDP only
(config/fastdds_udp.xml: no shared memory, which would bypass the network), discovery reaches the subnet
with the other host as a static peer (``ROS_STATIC_PEERS``). The recording, read back from the bag, must
equal the offline loop of `simulate` to 1e-6 in lockstep, and in realtime the robot must track paper-circle.
The veth's byte counters show the loop's traffic crossed it. Needs root (``ip netns``); skipped otherwise.
"""

from __future__ import annotations

import numpy as np
import pytest

from robotino_geom_mpc.bench.two_hosts import two_hosts_run
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.recording.bag_reader import BagReader
from robotino_geom_mpc.ros.plans import report_of_message
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.system.netns import netns_unavailable

pytestmark = [pytest.mark.ros, pytest.mark.skipif(netns_unavailable() is not None,
                                                  reason=str(netns_unavailable()))]

# realtime paper-circle over the veth: RMS position error after settling (measured 8.1e-6 m, max 1.5e-5 m,
# on 2 cores, none of 400 ticks missed); 0.1 mm leaves a margin of 12 for scheduling jitter
REALTIME_RMS_LIMIT_M = 1e-4
# the precision claim holds for a loop that keeps its deadlines: with more ticks missed (commands later
# than the next odometry, a host overloaded by other processes: 94 of 241 at load 12 on 2 cores gave
# 9 mm on localhost too) the test is skipped with the plant's figures
REALTIME_MISSED_LIMIT = 0.05


def _run(hosts, tmp_path, scenario: str, duration_s: float, lockstep: bool, plans: bool | None = None):
    """Run the loop across the two hosts, recorded on the controller's (`bench.two_hosts.two_hosts_run`)."""
    return two_hosts_run(hosts, tmp_path, scenario, duration_s, lockstep, plans)


def _load_guard(timing, limit: float = REALTIME_MISSED_LIMIT) -> None:
    """Skip with the plant's figures when more than `limit` of the ticks were missed."""
    missed = timing["missed"] / (timing["answered"] + timing["missed"])
    if missed > limit:
        pytest.skip(f"host overloaded: {timing['missed']} of {timing['answered'] + timing['missed']} ticks missed; "
                    "the tracking precision needs a loop that keeps its deadlines")


def test_lockstep_across_two_network_namespaces_equals_simulate(hosts, tmp_path):
    duration_s = 3.0
    robot, control = load_params()
    done = _run(hosts, tmp_path, "paper-circle", duration_s, lockstep=True)
    dds, crossed = done.run, done.plant_received_bytes
    offline = run_scenario(RunConfig("paper-circle", robot, control, duration_s=duration_s))
    assert dds.n == offline.n == round(duration_s / control.period_s)
    for name in ("t", "pose", "reference", "currents", "voltages"):
        np.testing.assert_allclose(getattr(dds, name), getattr(offline, name), rtol=1e-6, atol=1e-9, err_msg=name)
    # every tick's three voltages (a Float64MultiArray, > 100 bytes) crossed the veth to the plant's host
    assert crossed > 100 * offline.n


def test_realtime_across_two_network_namespaces_tracks_paper_circle(hosts, tmp_path):
    duration_s = 4.0
    done = _run(hosts, tmp_path, "paper-circle", duration_s, lockstep=False)
    dds, crossed, timing = done.run, done.plant_received_bytes, done.timing
    # the loop ran across the veth: the recording holds a second of it at least (in realtime the plant does
    # not wait for the others), most ticks were answered, each tick's commands crossed
    assert dds.n >= round(1.0 / dds.control_period_s)
    assert timing["answered"] > timing["missed"] and timing["latency_ms"]["median"] < 1e3 * dds.control_period_s
    assert crossed > 100 * dds.n
    _load_guard(timing)
    rms = compute_metrics(dds)["rms_position_error_m"]
    assert rms < REALTIME_RMS_LIMIT_M, rms


# a wifi run across the hosts: the topics of the loop with plans (the plant's emulated link, the controller's
# plans, the robot's reports of what it applied), each recorded on the controller's host
WIFI_TOPICS = ("odom", "ground_truth/odom", "wheel_currents", "wheel_voltages", "reference_preview",
               "wheel_voltage_plan", "command_applied", "diagnostics")
WIFI_RMS_LIMIT_M = 1e-3  # tracking, not the realtime figures (those are the `networked` benchmark's)
# with plans the plant counts a tick missed when no plan was taken between its odometry and the next: the
# link's loss (5 % each way, in bursts) and jitter (plans bunching, up to 15 ms each way) miss some on an idle
# host, so the load guard skips when most ticks are missed (a plan's CPU time beyond the period on a loaded
# host: 240 of 351 missed, 15.7 mm, at load 12 on 2 cores; 589 of about 1200 gave 60 um)
WIFI_MISSED_LIMIT = 0.5


def _payload_bytes(bag: BagReader, topic: str) -> int:
    """The CDR bytes of every message recorded on ``/<topic>`` (each crossed the veth as one sample at least)."""
    return sum(len(message.data) for message in bag.messages(["/" + topic]))


@pytest.mark.slow
def test_wifi_with_plans_across_two_network_namespaces_tracks_paper_circle(hosts, tmp_path):
    duration_s = 5.0
    done = _run(hosts, tmp_path, "wifi", duration_s, lockstep=False)
    bag = BagReader(done.bag)
    missing = [t for t in WIFI_TOPICS if "/" + t not in bag.topics or not bag.topics["/" + t].message_count]
    assert not missing, f"not recorded: {missing} (recorded: {bag.contents()})"
    # the plans reached the plant across the veth and its reports came back: the robot reports the receipt of
    # most plans the controller sent (its downlink loses some, DDS keeps the newest when the plant falls behind),
    # and of none it did not send; each sample crossed with its serialized bytes at least (the plain commands
    # stay on the controller's host, read by the recorder alone)
    sent = np.array(sorted(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                           for _, msg in bag.decoded(["/wheel_voltage_plan"])))
    reports = [report_of_message(msg) for _, msg in bag.decoded(["/command_applied"])]
    received = np.unique([round(r.basis_s * 1e9) for r in reports if r.values is None])
    # a report's basis in float seconds holds a stamp of about 1.8e9 s to 256 ns
    nearest = np.abs(received[:, None] - sent[None, :]).min(axis=1)
    assert nearest.max() < 1000 and len(received) > 0.5 * len(sent), (nearest.max(), len(received), len(sent))
    assert done.plant_received_bytes > _payload_bytes(bag, "wheel_voltage_plan")
    assert done.controller_received_bytes > sum(_payload_bytes(bag, t) for t in (
        "command_applied", "odom", "ground_truth/odom", "wheel_currents"))
    dds = done.run
    assert dds.n >= round(1.0 / dds.control_period_s)
    _load_guard(done.timing, WIFI_MISSED_LIMIT)
    # the robot ran on the plans: its reports of the periods applied name a plan's entry (index -1: none held)
    periods = [r for r in reports if r.values is not None]
    assert sum(r.entry_index >= 0 for r in periods) > 0.9 * len(periods) > 0
    rms = compute_metrics(dds)["rms_position_error_m"]
    assert rms < WIFI_RMS_LIMIT_M, rms
