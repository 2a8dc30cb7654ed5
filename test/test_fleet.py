"""The fleet (issue 40): N robots through one controller, one plant and one trajectory process (`ros.fleet`).

Lockstep: ``run --robots N`` records the fleet in one bag; each robot's metrics (its namespace of the bag) equal
the offline loop's of the same scenario and seed (`simulation.run_scenario`, the truth `run` is held to) to 1e-9,
and the plant counts every tick of every robot answered. Faults: the fleet controller in realtime fed by the
test, one robot's odometry stopped -> that robot's controller sends zero volts within its watchdog time while the
others go on tracking every odometry; one robot's ``~/enable`` (``/<ns>/robotino_controller/enable``) false ->
that robot zero, the others tracking.
"""

import json
import math
import os
import subprocess
import sys

import pytest
from std_srvs.srv import SetBool

from harness import Harness
from robotino_geom_mpc.offline.results import compute_metrics
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.reference.trajectories import make_reference
from robotino_geom_mpc.system.processes import NodeGroup, robot_names, ros_args
from test_controller_node import _rig, odometry, stamped_preview, values

pytestmark = pytest.mark.ros

DURATION_S = 2.0
SEED = 3
SCENARIO = "robustness"  # a mismatched controller model and odometry noise: the seed matters


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "robotino_geom_mpc", *args], capture_output=True, text=True,
                          timeout=600, env=os.environ.copy())


def _run_fleet(out, robots: int, scenario: str = SCENARIO) -> subprocess.CompletedProcess:
    return _cli("run", "--robots", str(robots), "--scenario", scenario, "--duration", str(DURATION_S), "--seed",
                str(SEED), "--out", str(out), "--no-plots")


def _assert_each_robot_is_the_single_run(out, robots: int, scenario: str = SCENARIO) -> None:
    robot, control = load_params()
    want = compute_metrics(run_scenario(RunConfig(scenario, robot, control, duration_s=DURATION_S, seed=SEED)))
    timing = json.loads((out / "timing.json").read_text())
    assert sorted(timing) == sorted(robot_names(robots))
    for namespace in robot_names(robots):
        assert timing[namespace]["ticks"] == round(DURATION_S / control.period_s), namespace
        assert timing[namespace]["missed"] == 0, namespace
        metrics = json.loads((out / namespace / "metrics.json").read_text())
        for key, value in want.items():
            if key.startswith("compute_time"):
                continue  # wall-clock measurements
            if isinstance(value, float) and math.isfinite(value):
                assert metrics[key] == pytest.approx(value, rel=0.0, abs=1e-9), (namespace, key)
            else:
                assert metrics[key] == value, (namespace, key)


@pytest.fixture(scope="module")
def fleet_of_two(tmp_path_factory):
    """A lockstep fleet of two on paper-circle (the nominal loop: `regress` replays it to 0 V)."""
    out = tmp_path_factory.mktemp("fleet") / "fleet2"
    proc = _run_fleet(out, 2, "paper-circle")
    assert proc.returncode == 0, proc.stderr + proc.stdout
    return out


@pytest.mark.parametrize("robots", [1, 5])
def test_lockstep_fleet_each_robot_is_the_single_robot_run(tmp_path, robots):
    out = tmp_path / f"fleet{robots}"
    proc = _run_fleet(out, robots)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    _assert_each_robot_is_the_single_run(out, robots)


def test_lockstep_fleet_of_two_each_robot_is_the_single_robot_run(fleet_of_two):
    _assert_each_robot_is_the_single_run(fleet_of_two, 2, "paper-circle")


def test_a_fleet_records_what_the_report_reads_without_the_optional_outputs(fleet_of_two):
    """The fleet's default leaves each robot's joint_states, /tf and predicted_path out (every robot's extra
    messages a tick; the report reads none of them: the metrics above came from this bag); each robot's loop
    topics are recorded, as the recording's own channel list (the mcap reader's) shows.
    """
    from mcap.reader import make_reader

    topics = set()
    for path in (fleet_of_two / "bag").glob("*.mcap"):
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
            assert summary is not None
            topics |= {channel.topic for channel in summary.channels.values()}
    assert "/tf" not in topics
    for namespace in robot_names(2):
        assert f"/{namespace}/joint_states" not in topics and f"/{namespace}/predicted_path" not in topics
        for topic in ("odom", "ground_truth/odom", "wheel_currents", "wheel_voltages", "reference_preview",
                      "diagnostics"):
            assert f"/{namespace}/{topic}" in topics, topic


def test_report_and_regress_read_one_robot_of_a_fleet_bag(fleet_of_two, tmp_path):
    """``report --namespace`` gives the robot's metrics as ``run`` wrote them; ``regress --namespace`` replays that
    robot's controller against its recorded commands; without a namespace the bag's two robots are ambiguous.
    """
    bag = fleet_of_two / "bag"
    for namespace in robot_names(2):
        proc = _cli("report", str(bag), "--namespace", namespace, "--out", str(tmp_path / namespace), "--no-plots")
        assert proc.returncode == 0, proc.stderr
        assert json.loads((tmp_path / namespace / "metrics.json").read_text()) == \
            json.loads((fleet_of_two / namespace / "metrics.json").read_text())
        proc = _cli("regress", str(bag), "--namespace", namespace)
        assert proc.returncode == 0 and proc.stdout.startswith("PASS"), proc.stderr + proc.stdout
    proc = _cli("report", str(bag), "--out", str(tmp_path / "all"), "--no-plots")
    assert proc.returncode == 2 and "several" in proc.stderr
    proc = _cli("report", str(bag), "--namespace", "robot3", "--out", str(tmp_path / "none"), "--no-plots")
    assert proc.returncode == 2 and "robot1, robot2" in proc.stderr


@pytest.mark.slow
def test_lockstep_fleet_of_20_each_robot_is_the_single_robot_run(tmp_path):
    out = tmp_path / "fleet20"
    proc = _run_fleet(out, 20)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    _assert_each_robot_is_the_single_run(out, 20)


ROBOTS = ("robot1", "robot2", "robot3")


def test_one_robots_stale_odometry_or_disable_zeroes_that_robot_only(tmp_path):
    _, control = load_params()
    reference = make_reference("paper-circle")
    period_ns = round(control.period_s * 1e9)
    with Harness("fleet_fault_test") as h, NodeGroup(log_dir=tmp_path) as group:
        rigs = {ns: _rig(h, f"/{ns}") for ns in ROBOTS}
        args = ros_args(None, {"mode": "realtime", "odom_timeout_s": 0.2, "reference_timeout_s": 0.2,
                               "robots": list(ROBOTS)})
        node = group.start("fleet_controller_node", args)
        assert h.spin_until(lambda: all(
            odom.get_subscription_count() >= 1 and preview.get_subscription_count() >= 1
            and h.node.count_publishers(f"/{ns}/wheel_voltages") >= 1
            for ns, (_, _, odom, preview) in rigs.items()), 60.0), node.stderr_tail()
        h.spin_for(0.2)

        def tracking(ns):
            return sum(values(d)[0].message == "tracking" for d in rigs[ns][1])

        last_stamp: dict[str, int] = {}  # each robot's last odometry fed

        def feed(robots, ticks, start):
            for k in range(start, start + ticks):
                stamp = h.node.get_clock().now().nanoseconds
                for ns in robots:
                    last_stamp[ns] = stamp
                    _, _, odom, preview = rigs[ns]
                    msg = stamped_preview(reference, k * period_ns, stamp, control)
                    msg.header.frame_id = f"{ns}/odom"  # each robot's frames carry its prefix
                    preview.publish(msg)
                    msg = odometry(stamp, 0.001, 0.0, 0.0)
                    msg.header.frame_id, msg.child_frame_id = f"{ns}/odom", f"{ns}/base_link"
                    odom.publish(msg)
                h.spin_for(0.02)
            return start + ticks

        k = 0
        while min(tracking(ns) for ns in ROBOTS) < 5 and k < 400:  # the first can arrive late (discovery)
            k = feed(ROBOTS, 1, k)
        assert min(tracking(ns) for ns in ROBOTS) >= 5, node.stderr_tail()

        # robot2's odometry stops; robot1 and robot3 go on, from robot2's answer to its last odometry on (its
        # status, published just after its voltages: a loaded host answers later than the feed's 20 ms)
        assert h.spin_until(lambda: any(d.header.stamp.sec * 10**9 + d.header.stamp.nanosec == last_stamp["robot2"]
                                        for d in rigs["robot2"][1]), 0.1), "robot2's last odometry not answered"
        h.spin_for(0.01)
        counts = {ns: (len(rigs[ns][0]), tracking(ns)) for ns in ROBOTS}
        k = feed(("robot1", "robot3"), 40, k)  # 0.8 s: robot2 stale after 0.2 s
        volts = {ns: [list(m.data) for m in rigs[ns][0]][counts[ns][0]:] for ns in ROBOTS}
        assert len(volts["robot2"]) >= 2 and all(v == [0.0, 0.0, 0.0] for v in volts["robot2"])
        assert "stale_odom" in [values(d)[1]["watchdog"] for d in rigs["robot2"][1]]
        for ns in ("robot1", "robot3"):  # every odometry answered with a tracking command, no zero
            assert tracking(ns) - counts[ns][1] >= 35, ns
            assert volts[ns] and all(v != [0.0, 0.0, 0.0] for v in volts[ns]), ns
            assert "stale_odom" not in [values(d)[1]["watchdog"] for d in rigs[ns][1]], ns

        # robot3 disabled through its own ~/enable; robot1 goes on
        client = h.node.create_client(SetBool, "/robot3/robotino_controller/enable")
        assert client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(SetBool.Request(data=False))
        assert h.spin_until(future.done, 10.0) and future.result().success
        counts = {ns: len(rigs[ns][0]) for ns in ("robot1", "robot3")}
        k = feed(("robot1", "robot3"), 20, k)
        assert all(list(m.data) == [0.0, 0.0, 0.0] for m in list(rigs["robot3"][0])[counts["robot3"]:])
        assert len(rigs["robot3"][0]) - counts["robot3"] >= 15
        assert all(list(m.data) != [0.0, 0.0, 0.0] for m in list(rigs["robot1"][0])[counts["robot1"]:])
        assert "Traceback" not in node.stderr_tail(200)


def test_robot_topics_and_parameters_are_per_robot(tmp_path):
    """Each robot's controller is ``/<ns>/robotino_controller`` with its own parameters (set on one: the others
    keep theirs) and its topics in its namespace.
    """
    with Harness("fleet_graph_test") as h, NodeGroup(log_dir=tmp_path) as group:
        node = group.start("fleet_controller_node", ros_args(None, {"mode": "realtime", "robots": list(ROBOTS)}))
        assert h.spin_until(lambda: all(h.node.count_publishers(f"/{ns}/wheel_voltages") >= 1 for ns in ROBOTS),
                            60.0), node.stderr_tail()
        names = {f"/{ns}/robotino_controller" for ns in ROBOTS} | {"/robotino_fleet_controller"}
        assert h.spin_until(lambda: names <= set(h.node.get_fully_qualified_node_names()), 30.0)
        (done,) = h.set_parameters("robot2/robotino_controller", {"control.q_x": 2.0e6})
        assert done.successful
        assert [h.get_parameters(f"{ns}/robotino_controller", ["control.q_x"])[0] for ns in ROBOTS][1] == 2.0e6
        others = [h.get_parameters(f"{ns}/robotino_controller", ["control.q_x", "frame_prefix"]) for ns in
                  ("robot1", "robot3")]
        assert others[0][0] == others[1][0] != 2.0e6
        assert [o[1] for o in others] == ["robot1/", "robot3/"]
        for ns in ROBOTS:
            subs = h.node.get_subscriptions_info_by_topic(f"/{ns}/odom")
            assert [(i.node_namespace, i.node_name) for i in subs] == [(f"/{ns}", "robotino_controller")]


def test_a_bad_robots_parameter_stops_the_fleet_with_status_2(tmp_path):
    with NodeGroup(log_dir=tmp_path) as group:
        node = group.start("fleet_controller_node", ros_args(None, {"robots": ["robot1", "robot1"]}))
        assert node.popen.wait(timeout=60) == 2
        assert "named twice" in node.stderr_tail()
