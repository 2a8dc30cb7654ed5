"""The Fast DDS profile the nodes get: when it is added, what it says, that Fast DDS takes it, what it saves."""

import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from robotino_geom_mpc.system.processes import dds_environment

pytestmark = pytest.mark.ros

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
    from robotino_geom_mpc.params.presets import default_params_file
    from robotino_geom_mpc.system.processes import PROFILE_SETTLE_S, node_arguments

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


# A reliable keep-all writer publishing `_BURST` samples, 0.2 ms apart, to a reader in another process, which
# exits once it has them all; the writer prints how often its participant's event thread (Fast DDS names it
# dds.ev.*) was switched during the burst, from the kernel's per-thread counters.
_BURST = 1000
_WRITER = f"""
import pathlib, sys, time
import rclpy
from rclpy.duration import Duration
from std_msgs.msg import String
from robotino_geom_mpc.ros.qos import LOCKSTEP_PUBLISH_QOS

def event_thread_switches():
    tasks = [t for t in pathlib.Path('/proc/self/task').iterdir() if (t / 'comm').read_text().startswith('dds.ev')]
    assert len(tasks) == 1, tasks
    fields = dict(line.split(':') for line in (tasks[0] / 'status').read_text().splitlines() if 'ctxt' in line)
    return sum(int(value) for value in fields.values())

rclpy.init()
node = rclpy.create_node('burst_writer')
pub = node.create_publisher(String, 'burst', LOCKSTEP_PUBLISH_QOS)
deadline = time.monotonic() + 30.0
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.01)
time.sleep(0.3)
before = event_thread_switches()
for k in range({_BURST}):
    pub.publish(String(data=str(k)))
    time.sleep(0.0002)  # a writer that leaves the CPU now and then, as a loop does, so that nothing coalesces
after = event_thread_switches()
assert pub.wait_for_all_acked(Duration(seconds=30.0))
print(after - before)
"""
_READER = f"""
import rclpy
from std_msgs.msg import String
from robotino_geom_mpc.ros.qos import LOCKSTEP_PUBLISH_QOS

rclpy.init()
node = rclpy.create_node('burst_reader')
got = []
node.create_subscription(String, 'burst', lambda msg: got.append(msg.data), LOCKSTEP_PUBLISH_QOS)
while len(got) < {_BURST}:
    rclpy.spin_once(node, timeout_sec=1.0)
assert got == [str(k) for k in range({_BURST})]
"""


def _event_thread_switches(profile: str) -> int:
    """The writer's event-thread context switches over the burst, both processes given `profile`."""
    env = {**os.environ, "FASTRTPS_DEFAULT_PROFILES_FILE": profile, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    reader = subprocess.Popen([sys.executable, "-c", _READER], env=env, stdin=subprocess.DEVNULL)
    try:
        out = subprocess.run([sys.executable, "-c", _WRITER], env=env, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and "XMLPARSER" not in out.stdout + out.stderr, out.stdout + out.stderr
        assert reader.wait(timeout=60) == 0
    finally:
        reader.kill()
        reader.wait()
    return int(out.stdout.split()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/task")
def test_a_sample_does_not_wake_the_writers_event_thread_once_per_reader(tmp_path):
    """Fast DDS 2.14 restarts a reader's NACK-suppression timer per sample; with the profile's 20 ms it runs
    (and wakes the event thread) about once per 20 ms, not once per sample: the kernel's counters of that thread
    over a 1000-sample burst (52-79 switches, also beside two busy cores), beside the same profile without the
    setting as the control (2213-3753).
    """
    (profile,) = dds_environment({}).values()
    tree = ET.parse(profile)
    (times,) = tree.getroot().findall("f:data_writer/f:times", NS)
    (suppression,) = times.findall("f:nackSupressionDuration", NS)
    assert int(suppression.find("f:sec", NS).text) + 1e-9 * int(suppression.find("f:nanosec", NS).text) == \
        pytest.approx(0.02)
    times.remove(suppression)
    control = tmp_path / "without_suppression.xml"
    ET.register_namespace("", NS["f"])  # Fast DDS wants its namespace as the default one
    tree.write(control, xml_declaration=True, encoding="UTF-8")
    shipped, without = _event_thread_switches(profile), _event_thread_switches(str(control))
    assert without > _BURST, without  # the mechanism: a wake-up (two switches) per sample
    assert shipped < _BURST / 5, (shipped, without)  # a run of the timer per 20 ms and heartbeats
