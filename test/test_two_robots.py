"""Two complete robots in one DDS domain, each in its own namespace (`processes.node_arguments(namespace=...)`).

Both loops run in lockstep at once (each plant's clock is remapped to ``<namespace>/clock``), on different
scenarios. Each robot's run, read by a probe in its namespace, equals the offline loop of its own scenario
(`simulation.run_scenario`) to 1e-6, and the DDS graph, sampled while the loops run, shows every endpoint of
a robot's topics in that robot's namespace, each node where it belongs, and no loop topic outside the two
namespaces but the global /tf, where each robot's frames carry its prefix (``robot1/odom``).
"""

import pytest
import threading
import time

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from tf2_msgs.msg import TFMessage

from harness import Harness
from probe import PROBE_WAIT_FOR, LoopProbe, ProbeSpinner
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.system.processes import NodeGroup, node_arguments
from robotino_geom_mpc.offline.simulation import RunConfig, run_scenario

pytestmark = pytest.mark.ros

DURATION_S = 3.0
ROBOTS = {"robot1": "paper-circle", "robot2": "lemniscate"}
# the loop's topics (relative) -> publishing node, and nodes that must subscribe
WIRING = {
    "wheel_voltages": ("robotino_controller", {"robotino_plant"}),
    "odom": ("robotino_plant", {"robotino_controller"}),
    "reference_preview": ("robotino_trajectory", {"robotino_controller"}),
    "clock": ("robotino_plant", {"robotino_trajectory"}),
    "ground_truth/odom": ("robotino_plant", set()),
    "wheel_currents": ("robotino_plant", set()),
}
# global by convention: the robots' frames are kept apart on /tf by their frame prefixes
GLOBAL_TOPICS = {"/rosout", "/parameter_events", "/tf", "/tf_static"}


class NamespacedProbe(ProbeSpinner):
    """`ProbeSpinner` whose probe (relative topics) lives in `namespace`: a global ``__ns`` remap of its context."""

    def __init__(self, namespace: str) -> None:
        self.context = Context()
        rclpy.init(args=["--ros-args", "-r", f"__ns:=/{namespace}"], context=self.context)
        self.probe = LoopProbe(self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.probe)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()


def _graph(harness: Harness, seen: set, topics: set) -> None:
    """Add the endpoints of the robots' loop topics to `seen`: (topic, kind, node namespace, node name)."""
    node = harness.node
    topics.update(name for name, _ in node.get_topic_names_and_types())
    for namespace in ROBOTS:
        for topic in WIRING:
            name = f"/{namespace}/{topic}"
            for kind, infos in (("pub", node.get_publishers_info_by_topic(name)),
                                ("sub", node.get_subscriptions_info_by_topic(name))):
                # an endpoint may be discovered before its node's name (ros_discovery_info): named later
                seen.update((name, kind, i.node_namespace, i.node_name) for i in infos
                            if i.node_name != "_NODE_NAME_UNKNOWN_")


def test_two_namespaced_robots_track_their_own_references_without_crossing(tmp_path):
    params = default_params_file()
    robot, control = load_params(params)
    probes = {ns: NamespacedProbe(ns) for ns in ROBOTS}
    seen: set = set()
    topics: set = set()
    try:
        with Harness("robotino_graph_watch") as harness, NodeGroup(log_dir=tmp_path / "robot1") as group1, \
                NodeGroup(log_dir=tmp_path / "robot2") as group2:
            transforms = harness.collect("/tf", TFMessage)
            plants = {}
            for (namespace, scenario), group in zip(ROBOTS.items(), (group1, group2)):
                # and this harness's /tf reader: a lockstep run can end before it matched (no frame of that robot)
                args = node_arguments(scenario, params, DURATION_S, lockstep=True,
                                      wait_for=[*PROBE_WAIT_FOR, "/tf:1"], namespace=namespace)
                started = {name: group.start(name, argv) for name, argv in args.items()}
                plants[namespace] = (group, started["plant_node"])
            deadline = time.monotonic() + 240.0
            while any(p.popen.poll() is None for _, p in plants.values()) and time.monotonic() < deadline:
                group1.check(), group2.check()  # a failed node fails the test now
                _graph(harness, seen, topics)
                harness.spin_for(0.05)
            for namespace, (group, plant) in plants.items():
                assert group.wait(plant, 1.0), f"{namespace}: {plant.stderr_tail()}"
                assert plant.popen.returncode == 0, plant.stderr_tail()
            harness.spin_for(0.3)
        for probe in probes.values():
            probe.wait_for_ticks(round(DURATION_S / control.period_s))
        runs = {ns: probes[ns].probe.run_data(scenario, params) for ns, scenario in ROBOTS.items()}
    finally:
        for probe in probes.values():
            probe.close()

    for namespace, scenario in ROBOTS.items():
        offline = run_scenario(RunConfig(scenario, robot, control, duration_s=DURATION_S))
        dds = runs[namespace]
        assert dds.n == offline.n == round(DURATION_S / control.period_s), namespace
        for name in ("t", "pose", "reference", "currents", "voltages"):
            np.testing.assert_allclose(getattr(dds, name), getattr(offline, name), rtol=1e-6, atol=1e-9,
                                       err_msg=f"{namespace} ({scenario}): {name}")
    # the two references differ: a probe fed by the other robot could not match both
    assert np.abs(runs["robot1"].reference - runs["robot2"].reference).max() > 0.1

    # no crossing: every endpoint of a robot's topic is a node of that robot (or its probe)
    for topic, kind, node_namespace, node_name in seen:
        assert node_namespace == "/" + topic.split("/")[1], (topic, kind, node_namespace, node_name)
    for namespace in ROBOTS:
        for topic, (publisher, subscribers) in WIRING.items():
            name = f"/{namespace}/{topic}"
            assert {n for t, k, _, n in seen if t == name and k == "pub"} == {publisher}, name
            assert subscribers <= {n for t, k, _, n in seen if t == name and k == "sub"}, name
    frames = {(t.header.frame_id, t.child_frame_id) for msg in transforms for t in msg.transforms}
    assert {(f"{ns}/odom", f"{ns}/base_link") for ns in ROBOTS} <= frames
    for parent, child in frames:  # every transform within one robot's frames
        assert parent.split("/")[0] == child.split("/")[0] in ROBOTS, (parent, child)
    stray = {t for t in topics - GLOBAL_TOPICS if not t.startswith(tuple(f"/{ns}/" for ns in ROBOTS))}
    assert not stray, f"loop topics outside the robots' namespaces: {sorted(stray)}"
