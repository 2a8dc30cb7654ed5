"""`system.netns` without root: the reason it cannot run, refused before anything is made."""

from __future__ import annotations

import subprocess

import pytest

from robotino_geom_mpc.system import netns
from robotino_geom_mpc.system.netns import Hosts, NetnsUnavailable, netns_unavailable, two_hosts

pytestmark = pytest.mark.unit


def test_without_root_or_iproute2_the_reason_is_named(monkeypatch):
    monkeypatch.setattr(netns.os, "geteuid", lambda: 1000)
    assert "root" in netns_unavailable()
    monkeypatch.setattr(netns.os, "geteuid", lambda: 0)
    monkeypatch.setattr(netns.shutil, "which", lambda name: None)
    assert "iproute2" in netns_unavailable()
    monkeypatch.setattr(netns.shutil, "which", lambda name: "/usr/sbin/ip")
    assert netns_unavailable() is None


def test_two_hosts_refuses_without_running_ip(monkeypatch):
    calls = []
    monkeypatch.setattr(netns.os, "geteuid", lambda: 1000)
    monkeypatch.setattr(netns.subprocess, "run", lambda *a, **k: calls.append(a))
    with pytest.raises(NetnsUnavailable, match="root"):
        with two_hosts():
            pass
    assert calls == []


def test_a_namespace_the_kernel_refuses_is_unavailable_and_nothing_is_left(monkeypatch):
    calls = []

    def run(argv, check=False, **kwargs):
        calls.append(argv)
        if argv[1:3] == ["netns", "add"] and check:
            raise subprocess.CalledProcessError(1, argv, stderr="mount --make-shared /run/netns failed: Operation "
                                                "not permitted\n")
        return subprocess.CompletedProcess(argv, 0, "", "")

    monkeypatch.setattr(netns, "netns_unavailable", lambda: None)
    monkeypatch.setattr(netns.subprocess, "run", run)
    with pytest.raises(NetnsUnavailable, match="Operation not permitted"):
        with two_hosts():
            pass
    # the first namespace failed: only the veth's cleanup ran, no namespace to delete
    assert [argv[:3] for argv in calls[1:]] == [["ip", "link", "del"]]


def test_the_hosts_prefix_and_dds_environment():
    hosts = Hosts(("a", "b"), ("va", "vb"), ("10.0.0.1", "10.0.0.2"))
    assert hosts.prefix(1) == ("ip", "netns", "exec", "b")
    env = hosts.dds_environment()
    assert env["ROS_STATIC_PEERS"] == "10.0.0.1;10.0.0.2" and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"].endswith("fastdds_udp.xml")
    assert "<useBuiltinTransports>false</useBuiltinTransports>" in open(env["FASTRTPS_DEFAULT_PROFILES_FILE"]).read()
