"""The views in config/: the RViz config and the Foxglove layout name topics the demo bag has, with their types.

The demo bag is a short lockstep run recorded by ``robotino-geom-mpc run --duration 3`` (conftest's
`paper_circle_run`); it is read with an independent reader (rosbags). Each topic a view names must be in the bag
with the type its display or panel takes (RViz: by display class; Foxglove 3D: paths and odometry, the URDF layer a
String; plots: every message path resolves, on the bag's messages, to numbers as Foxglove's plot reads them
(numeric strings too); the nominal-current reference lines are the preset's nominal current). RViz's fixed frame is
the frame of the bag's odometry and the parent of its base_link transform.
"""

import json
import math
import re
from collections import defaultdict

import pytest
import yaml
from rosbags.highlevel import AnyReader

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.params.presets import config_file

pytestmark = pytest.mark.ros

RVIZ = config_file("robotino.rviz")
FOXGLOVE = config_file("robotino_foxglove_layout.json")
RVIZ_TYPES = {  # display class -> the message type it reads
    "rviz_default_plugins/Path": "nav_msgs/msg/Path",
    "rviz_default_plugins/Odometry": "nav_msgs/msg/Odometry",
    "rviz_default_plugins/RobotModel": "std_msgs/msg/String",
}
FOXGLOVE_3D_TYPES = ("nav_msgs/msg/Path", "nav_msgs/msg/Odometry")
SAMPLES = 50  # messages per topic on which each plotted path is evaluated


@pytest.fixture(scope="module")
def demo_bag(paper_circle_run):
    """The demo's bag (a shorter paper-circle run, conftest's): its types by topic and the first `SAMPLES` decoded
    messages of each topic.
    """
    out, run, _ = paper_circle_run
    assert run.returncode == 0, run.stderr[-3000:]
    types, messages = {}, defaultdict(list)
    with AnyReader([out / "bag"]) as reader:
        for connection in reader.connections:
            types[connection.topic] = connection.msgtype
        for connection, _, raw in reader.messages():
            if len(messages[connection.topic]) < SAMPLES:
                messages[connection.topic].append(reader.deserialize(raw, connection.msgtype))
    return types, messages


def _rviz_topics(tree) -> list[tuple[str, str]]:
    """(display class, topic) of every display of the RViz config with a topic."""
    found = []
    for display in tree["Visualization Manager"]["Displays"]:
        for key in ("Topic", "Description Topic"):
            if key in display:
                found.append((display["Class"], display[key]["Value"]))
    return found


def test_the_rviz_view_names_topics_of_the_demo_bag_with_their_types(demo_bag):
    types, messages = demo_bag
    tree = yaml.safe_load(RVIZ.read_text())
    topics = _rviz_topics(tree)
    assert {t for _, t in topics} == {"/robot_description", "/reference_path", "/predicted_path", "/odom"}
    for display, topic in topics:
        assert types.get(topic) == RVIZ_TYPES[display], (display, topic, types.get(topic))
    classes = [d["Class"] for d in tree["Visualization Manager"]["Displays"]]
    assert "rviz_default_plugins/TF" in classes and types["/tf"] == "tf2_msgs/msg/TFMessage"
    (model,) = [d for d in tree["Visualization Manager"]["Displays"] if d["Class"].endswith("RobotModel")]
    assert model["Description Source"] == "Topic"
    fixed = tree["Visualization Manager"]["Global Options"]["Fixed Frame"]
    assert fixed == "odom" and {m.header.frame_id for m in messages["/odom"]} == {fixed}
    parents = {t.header.frame_id for m in messages["/tf"] for t in m.transforms if t.child_frame_id == "base_link"}
    assert parents == {fixed}
    assert "<Fixed Frame>" in RVIZ.read_text()


def _path_values(message, path: str) -> list:
    """Evaluate a Foxglove message path (after its topic): ``.field``, ``[i]``, ``[:]``, ``{key=="value"}``."""
    values = [message]
    for token in re.findall(r'\.\w+|\[\d+\]|\[:\]|\{\w+=="[^"]*"\}', path):
        if token.startswith("."):
            values = [getattr(v, token[1:]) for v in values]
        elif token == "[:]":
            values = [item for v in values for item in v]
        elif token.startswith("["):
            values = [v[int(token[1:-1])] for v in values]
        else:
            key, wanted = re.fullmatch(r'\{(\w+)=="([^"]*)"\}', token).groups()
            values = [v for v in values if getattr(v, key) == wanted]
    assert "".join(re.findall(r'\.\w+|\[\d+\]|\[:\]|\{\w+=="[^"]*"\}', path)) == path, path  # nothing left out
    return values


def _number(value) -> float:
    """A value as Foxglove's plot takes it: numbers, and strings that read as numbers."""
    number = float(value)
    assert math.isfinite(number)
    return number


def test_the_foxglove_layout_names_topics_of_the_demo_bag_and_its_plots_read_numbers(demo_bag):
    types, messages = demo_bag
    layout = json.loads(FOXGLOVE.read_text())
    panels = layout["configById"]
    kinds = {name.split("!")[0] for name in panels}
    assert {"3D", "Plot", "DiagnosticSummary"} <= kinds
    (three_d,) = [p for name, p in panels.items() if name.startswith("3D!")]
    for topic in three_d["topics"]:
        assert types.get(topic) in FOXGLOVE_3D_TYPES, topic
    (urdf,) = [layer for layer in three_d["layers"].values() if layer["layerId"] == "foxglove.Urdf"]
    assert urdf["sourceType"] == "topic" and types[urdf["topic"]] == "std_msgs/msg/String"
    assert "<robot" in messages[urdf["topic"]][0].data
    assert three_d["followTf"] == "odom" and types["/tf"] == "tf2_msgs/msg/TFMessage"
    for name, panel in panels.items():
        if name.startswith("DiagnosticSummary!"):
            assert types[panel["topicToRender"]] == "diagnostic_msgs/msg/DiagnosticArray"
    nominal = load_params()[0].nominal_current_a
    plotted, references = set(), []
    for name, panel in panels.items():
        if not name.startswith("Plot!"):
            continue
        for series in panel["paths"]:
            value = series["value"]
            if re.fullmatch(r"-?[0-9.]+", value):  # a reference line
                references.append((name, float(value)))
                continue
            topic, path = re.match(r"(/[\w/]+)(.*)", value).groups()
            assert topic in types, value
            got = [_number(v) for m in messages[topic] for v in _path_values(m, path)]
            assert got and len(got) >= len(messages[topic]) // 2, (value, len(got))
            plotted.add(topic)
    assert plotted == {"/wheel_currents", "/wheel_voltages", "/diagnostics"}
    assert sorted(references) == [("Plot!currents", -nominal), ("Plot!currents", nominal)]
    assert "layout" in layout and all(isinstance(p, dict) for p in panels.values())

