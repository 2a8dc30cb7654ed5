"""The fleet's faults over DDS (issue 40): its controller killed, one robot's odometry stopping in lockstep.

* Realtime: the fleet plant, trajectory and controller of three robots as ``run --robots 3`` starts them
  (`processes.fleet_arguments`); the fleet controller SIGKILLed while every robot tracks: each robot's plant holds
  its last command for ``command_timeout_s`` (its drive watchdog, 0.1 s), then applies zero volts (read from its
  ``joint_states``: U = R i + Km gear omega), and logs the watchdog's stop under that robot's name. The fleet
  runs without plans (``run --robots`` refuses a link and ``--plans``), so the watchdog is the robot side's
  only stop; plan exhaustion has no fleet case.
* Lockstep: the fleet's one clock waits for every robot (`plant_lockstep.FleetClock`), so a robot whose odometry
  stops holds the whole fleet, by design: simulated time stops for everyone, nobody's watchdog fires (it counts
  simulated time) and the run goes on unchanged when the odometry comes back. Robot 2's odometry goes through a
  relay in the test (the fleet plant's ``/robot2/odom`` remapped to ``/robot2/odom_plant``) that drops it for
  2 s: meanwhile no robot's tick advances past robot 2's first lost one, the fleet plant resends robot 2's
  tick and holds the others' (their resend counts 0), and afterwards every robot's run, read by a probe in its
  namespace, equals its single-robot run (`simulation.run_scenario`) to 1e-9.
"""

import json
import os
import signal

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from harness import DEEP_QOS, Harness
from probe import PROBE_WAIT_FOR
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.ros.messages import stamp_to_ns
from robotino_geom_mpc.system.processes import NodeGroup, fleet_arguments, robot_names
from test_controller_node import values
from test_fault_controller import _implied_voltages
from test_two_robots import NamespacedProbe

pytestmark = [pytest.mark.ros, pytest.mark.slow]  # each about 9 s alone (the processes' start, discovery)

ROBOTS = 3
COMMAND_TIMEOUT_S = 0.1  # the plant's default drive watchdog
ZERO_V = 0.5  # |U| below this is zero volts (back-EMF braking; the inductance's di/dt aside), as test_fault_controller


def test_the_fleet_controller_killed_every_robots_plant_stops_within_its_watchdog(tmp_path):
    robot, control = load_params()
    names = robot_names(ROBOTS)
    args = fleet_arguments("paper-circle", default_params_file(), 120.0, lockstep=False, robots=ROBOTS,
                           overrides={"plant_node": {"publish_joint_states": True,
                                                     "command_timeout_s": COMMAND_TIMEOUT_S}})
    with Harness("fleet_kill_test") as h, NodeGroup(log_dir=tmp_path) as group:
        joints = {ns: h.collect(f"/{ns}/joint_states", JointState) for ns in names}
        diagnostics = {ns: h.collect(f"/{ns}/diagnostics", DiagnosticArray) for ns in names}
        nodes = {name: group.start(name, argv) for name, argv in args.items()}

        def tracking(ns):
            return sum(values(d)[0].message == "tracking" for d in diagnostics[ns])

        # every robot tracking for a second (100 ticks) before the kill
        assert h.spin_until(lambda: min(tracking(ns) for ns in names) >= 100, 90.0), \
            nodes["fleet_controller_node"].stderr_tail()
        os.killpg(nodes["fleet_controller_node"].popen.pid, signal.SIGKILL)
        kill_ns = h.node.get_clock().now().nanoseconds
        nodes["fleet_controller_node"].popen.wait()
        stop_ns = kill_ns + round((COMMAND_TIMEOUT_S + 2 * control.period_s) * 1e9)
        # half a second of joint states after the watchdog's stop, for every robot
        assert h.spin_until(lambda: all(sum(stamp_to_ns(j.header.stamp) > stop_ns for j in joints[ns]) >= 40
                                        for ns in names), 30.0), nodes["fleet_plant_node"].stderr_tail()
        assert nodes["fleet_plant_node"].popen.poll() is None and nodes["fleet_trajectory_node"].popen.poll() is None
    plant_log = "".join(path.read_text() for path in (nodes["fleet_plant_node"].stdout_path,
                                                      nodes["fleet_plant_node"].stderr_path))
    for ns in names:
        volts = [(stamp_to_ns(j.header.stamp), np.abs(_implied_voltages(j, robot)).max()) for j in joints[ns]]
        before = [u for stamp, u in volts if stamp < kill_ns]
        after = [u for stamp, u in volts if stamp > stop_ns]
        assert max(before[-50:]) > 1.0, (ns, before[-50:])  # the robot was driven on the circle
        assert max(after) < ZERO_V, (ns, after)
        zero = min(stamp for stamp, u in volts if stamp > kill_ns and u < ZERO_V)
        print(f"\n{ns}: zero volts {(zero - kill_ns) * 1e-9:.3f} s after the fleet controller's SIGKILL")
        # the robot's own drive watchdog stopped it (its logger is the robot's plant's)
        assert any(f"[{ns}.robotino_plant]" in line and "zero volts (drive watchdog" in line
                   for line in plant_log.splitlines()), (ns, plant_log[-2000:])
    assert "Traceback" not in plant_log


LOCKSTEP_S = 2.0
STOP_AT_S = 0.5  # robot 2's odometry is dropped from its first tick at or after this simulated time
# wall time: the tick and at least two resends lost too (lockstep_resend_s 0.5 s, checked every 0.25 s: each resend
# comes 0.5-0.75 s after the send before it, so the second by 1.5 s; 1.5 s itself put it on the outage's edge)
OUTAGE_S = 2.0


def test_lockstep_one_robots_odometry_stopping_holds_the_fleet_and_changes_no_run(tmp_path):
    robot, control = load_params()
    params = default_params_file()
    names = robot_names(ROBOTS)
    report = tmp_path / "timing.json"
    wait_for = [f"/clock:{ROBOTS}" if w.startswith("/clock:") else w for w in PROBE_WAIT_FOR]
    args = fleet_arguments("paper-circle", params, LOCKSTEP_S, lockstep=True, robots=ROBOTS,
                           overrides={"plant_node": {"lockstep_wait_for": wait_for, "timing_report": str(report)}})
    args["fleet_plant_node"] += ["-r", "/robot2/odom:=/robot2/odom_plant"]
    probes = {ns: NamespacedProbe(ns) for ns in names}
    try:
        with Harness("fleet_lockstep_outage_test") as h, NodeGroup(log_dir=tmp_path) as group:
            clock = h.collect("/clock", Clock)
            others = {ns: h.collect(f"/{ns}/odom", Odometry) for ns in ("robot1", "robot3")}
            relay = h.node.create_publisher(Odometry, "/robot2/odom", DEEP_QOS)
            outage: dict = {"start": None, "dropped": []}

            def forward(msg: Odometry) -> None:
                now = h.node.get_clock().now().nanoseconds
                if outage["start"] is None and stamp_to_ns(msg.header.stamp) >= STOP_AT_S * 1e9:
                    outage["start"] = now
                if outage["start"] is not None and now - outage["start"] < OUTAGE_S * 1e9:
                    outage["dropped"].append(stamp_to_ns(msg.header.stamp))
                    return
                relay.publish(msg)

            h.node.create_subscription(Odometry, "/robot2/odom_plant", forward, DEEP_QOS)
            nodes = {name: group.start(name, argv) for name, argv in args.items()}
            plant = nodes["fleet_plant_node"]
            assert h.spin_until(lambda: outage["start"] is not None, 90.0), plant.stderr_tail()
            h.spin_for(OUTAGE_S - 0.1)  # the fleet as it stands at the outage's end
            outage["clock"] = max(stamp_to_ns(c.clock) for c in clock)
            outage["odom"] = {ns: [stamp_to_ns(o.header.stamp) for o in odom] for ns, odom in others.items()}
            # the relay forwards while the run goes on
            assert h.spin_until(lambda: plant.popen.poll() is not None, 120.0), plant.stderr_tail()
            assert plant.popen.returncode == 0, plant.stderr_tail()
        for probe in probes.values():
            probe.wait_for_ticks(round(LOCKSTEP_S / control.period_s))
        runs = {ns: probes[ns].probe.run_data("paper-circle", params) for ns in names}
    finally:
        for probe in probes.values():
            probe.close()

    # the outage: robot 2's first lost tick and its resends (one tick, sent again, counted by the plant), and the
    # fleet held at it: the clock and the other robots' odometry no further, their tick sent once (held, no resend)
    lost = outage["dropped"]
    assert len(lost) >= 3 and len(set(lost)) == 1, lost
    assert json.loads(report.read_text())["robot2"]["resent"] >= len(lost) - 1
    assert outage["clock"] == lost[0], (outage["clock"], lost[0])
    for ns, stamps in outage["odom"].items():
        assert max(stamps) == lost[0] and stamps.count(lost[0]) == 1, ns
    # and no run changed: each is its single-robot run
    offline = run_scenario(RunConfig("paper-circle", robot, control, duration_s=LOCKSTEP_S))
    want = compute_metrics(offline)
    for ns in names:
        dds = runs[ns]
        assert dds.n == offline.n == round(LOCKSTEP_S / control.period_s), ns
        for name in ("t", "pose", "reference", "currents", "voltages"):
            np.testing.assert_allclose(getattr(dds, name), getattr(offline, name), rtol=0.0, atol=1e-9,
                                       err_msg=f"{ns}: {name}")
        got = compute_metrics(dds)  # the metrics of what the probe reads (no odometry: the ground truth's)
        common = [key for key in want.keys() & got.keys() if isinstance(want[key], float)
                  and not key.startswith("compute_time")]  # wall-clock measurements
        assert "rms_position_error_m" in common and "max_position_error_m" in common, sorted(got)
        for key in common:
            assert got[key] == pytest.approx(want[key], rel=0.0, abs=1e-9, nan_ok=True), (ns, key)
