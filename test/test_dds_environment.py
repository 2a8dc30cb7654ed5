"""The Fast DDS profile the nodes get: when it is added, what it says, that Fast DDS takes it."""

import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from robotino_geom_mpc.ros.processes import dds_environment

NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_added_for_every_discovery_range_unless_the_user_names_a_profile():
    ranges = ({}, *({"ROS_AUTOMATIC_DISCOVERY_RANGE": r} for r in ("LOCALHOST", "SUBNET", "SYSTEM_DEFAULT")))
    added = [dds_environment(env) for env in ranges]
    assert all(a == added[0] and list(a) == ["FASTRTPS_DEFAULT_PROFILES_FILE"] for a in added)
    for env in ranges:
        assert dds_environment({**env, "FASTRTPS_DEFAULT_PROFILES_FILE": "/mine.xml"}) == {}
    (path,) = added[0].values()
    # read by an XML parser of its own: the default participant profile announces every 0.1 s
    (profile,) = ET.parse(path).getroot().findall("f:participant", NS)
    assert profile.get("is_default_profile") == "true"
    period = profile.find("f:rtps/f:builtin/f:discovery_config/f:leaseAnnouncement", NS)
    assert int(period.find("f:sec", NS).text) + 1e-9 * int(period.find("f:nanosec", NS).text) == pytest.approx(0.1)


def test_fast_dds_loads_the_profile_without_complaint():
    env = dds_environment({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    code = "import rclpy; rclpy.init(); n = rclpy.create_node('profile_check'); n.destroy_node(); rclpy.shutdown()"
    out = subprocess.run([sys.executable, "-c", code], env={**os.environ, **env}, capture_output=True, text=True,
                         timeout=60)
    log = out.stdout + out.stderr  # Fast DDS logs to stdout
    assert out.returncode == 0, log
    assert "XMLPARSER" not in log and "Error" not in log, log


def test_a_lockstep_plant_settles_shorter_only_with_the_profile(monkeypatch):
    """`node_arguments` gives the plant PROFILE_SETTLE_S when the nodes get the profile; otherwise the plant's own."""
    from robotino_geom_mpc.core.params import default_params_file
    from robotino_geom_mpc.ros.processes import PROFILE_SETTLE_S, node_arguments

    def settle(lockstep: bool) -> list[str]:
        argv = node_arguments("paper-circle", default_params_file(), 1.0, lockstep)["plant_node"]
        return [a for a in argv if a.startswith("lockstep_settle_s:=")]

    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    assert settle(True) == [f"lockstep_settle_s:={PROFILE_SETTLE_S:g}"] and settle(False) == []
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET")  # a plain shell: the same profile, the same settle
    assert settle(True) == [f"lockstep_settle_s:={PROFILE_SETTLE_S:g}"]
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", "/mine.xml")  # the user's own profile: the plant's default
    assert settle(True) == []
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE")
    # the nodes' environment decides, not the caller's: nodes given another profile (two hosts) keep the default
    udp = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "FASTRTPS_DEFAULT_PROFILES_FILE": "/udp.xml"}
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    argv = node_arguments("paper-circle", default_params_file(), 1.0, True, environ=udp)["plant_node"]
    assert not [a for a in argv if a.startswith("lockstep_settle_s:=")]
    argv = node_arguments("paper-circle", default_params_file(), 1.0, True,
                          environ={"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})["plant_node"]
    assert f"lockstep_settle_s:={PROFILE_SETTLE_S:g}" in argv
