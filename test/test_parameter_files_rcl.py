r"""Parameter files as rcl reads them: the pre-check every node makes before `rclpy.init` (`params.files`)
and rcl itself agree on which files they refuse and on the values a node gets.

The truth is rcl: each file is given to ``rclpy.init(args=[..., "--ros-args", "--params-file", FILE])`` in a
fresh process (rcl_yaml_param_parser parses it there; a file it refuses raises), and a node of the file's
name and namespace is created to read the overrides rclpy matched to it (``Node._parameter_overrides``, the
dict rclpy builds from rcl's parse: rclpy has no public accessor for it). The pre-check's values for the
node are the sections `params.files.parse_parameter_file` reads, merged in the file's order where rclpy's
node-name pattern (``/*`` -> ``(/\w+)``, rclpy's node.cpp) matches the node: an independent rule.

Cases: the forms launch_ros writes (``!!python/tuple`` lists, ``/<node>`` and ``/**`` keys; the real files
are pinned in test_launch_file), anchors, an alias, flow style, nested namespaces, wildcards, keys with and
without a leading slash, a YAML error, a sequence of mixed types, an empty value, an invalid node name, and
scalars that YAML 1.1 and rcl type differently.

One difference is left out: the rcl of the PyPI wheels links an old libyaml (soname 2.0.5) that refuses
a ':' inside a plain scalar of a flow sequence (``[odom:1]``), which libyaml 0.2.5 (a Jazzy install's, and
PyYAML's, which the pre-check uses) reads; there the pre-check accepts and rcl's refusal still stops the node
with one line (`ros.spin.start_rclpy`). Then the refusals that are the package's own (rcl accepts
the file): an unknown key, a wrong type, a value out of range, an empty list for a declared parameter.
"""

import json
import math
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from robotino_geom_mpc.params.files import check_parameter_files, parse_parameter_file
from robotino_geom_mpc.params.presets import default_params_file
from robotino_geom_mpc.params.rcl_yaml import NO_VALUE
from robotino_geom_mpc.params.specs import ParamError

pytestmark = pytest.mark.ros

PROBE = textwrap.dedent("""\
    import json, math, sys
    import rclpy
    from rclpy.node import Node

    def plain(v):
        if isinstance(v, float) and not math.isfinite(v):
            return repr(v)
        return [plain(x) for x in v] if isinstance(v, (list, tuple)) or type(v).__name__ == "array" else v

    for line in sys.stdin:
        path, name, namespace = json.loads(line)
        context = rclpy.Context()
        try:
            rclpy.init(args=["probe", "--ros-args", "--params-file", path], context=context)
        except Exception as exc:
            print(json.dumps({"refused": str(exc).splitlines()[0]}), flush=True)
            continue
        node = Node(name, namespace=namespace, context=context)
        values = {k: [p.type_.name, plain(p.value)] for k, p in node._parameter_overrides.items()}
        node.destroy_node()
        rclpy.shutdown(context=context)
        print(json.dumps({"values": values}), flush=True)
    """)
_KIND = {bool: "BOOL", int: "INTEGER", float: "DOUBLE", str: "STRING"}

PLANT = "/robotino_plant"
LAUNCH_ROS_PLANT = """\
/robotino_plant:
  ros__parameters:
    duration_s: 8.0
    frame_prefix: ''
    lockstep_wait_for: !!python/tuple
    - odom:2
    - /clock:2
    - reference_preview:2
    mode: lockstep
    odometry_noise.position_m: 0.001
    seed: 0
"""
SCALARS = ["1", "010", "08", "0x1f", "-0x10", "nan", ".nan", "-.inf", "inf", "Infinity", ".5", "1.", "1e6", "2E-3",
           "1e400", "yes", "y", "N", "off", "oFF", "~", "null", "1_000", "+1", "9223372036854775808", "'3'", '"x"',
           "!!str 12", "!!float 1", "abc", "' '", "[1, 2]", "[yes, no]", "!!python/tuple [a, b]", "[]",
           "|\n      12", "{a: {b: 2}, c: 3}"]

# case -> (file text, the fully qualified node name that reads it), every key one our nodes declare
CASES = {
    "launch_ros python tuple": (LAUNCH_ROS_PLANT, PLANT),
    "launch_ros /** section": ("/**:\n  ros__parameters:\n    frame_prefix: ''\n    mode: lockstep\n",
                               "/robot_description_publisher"),
    "anchors": ("/**:\n  ros__parameters: &common\n    mode: &m lockstep\nrobotino_plant:\n  ros__parameters:\n"
                "    seed: &s 3\n    lockstep_wait_for: &w\n    - odom:1\n    - /clock:1\n", PLANT),
    "an alias": ("robotino_plant:\n  ros__parameters:\n    seed: &s 3\n    duration_s: 1.0\n"
                 "robotino_controller:\n  ros__parameters:\n    mode: *s\n", PLANT),
    "flow style": ("{/robotino_plant: {ros__parameters: {odometry_noise: {position_m: 0.001, yaw_rad: 2e-3},"
                   " seed: 4}}, /**: {ros__parameters: {mode: lockstep}}}\n", PLANT),
    "nested namespaces": ("robot1:\n  robotino_plant:\n    ros__parameters:\n      seed: 5\n"
                          "  robotino_controller:\n    ros__parameters:\n      odom_timeout_s: 0.2\n",
                          "/robot1/robotino_plant"),
    "nested namespace, another robot": ("robot2:\n  robotino_plant:\n    ros__parameters:\n      seed: 5\n",
                                        "/robot1/robotino_plant"),
    "wildcards": ("/**/robotino_plant:\n  ros__parameters:\n    seed: 6\n/*:\n  ros__parameters:\n"
                  "    mode: lockstep\n/robot1/*:\n  ros__parameters:\n    duration_s: 2.0\n",
                  "/robot1/robotino_plant"),
    "keys with and without a leading slash": ("robotino_plant:\n  ros__parameters:\n    seed: 1\n    duration_s: 3.0\n"
                                              "/robotino_plant:\n  ros__parameters:\n    seed: 2\n", PLANT),
    "a YAML error": ("robotino_plant:\n  ros__parameters:\n    lockstep_wait_for: [odom:1\n", PLANT),
    "a sequence of mixed types": ("robotino_plant:\n  ros__parameters:\n    lockstep_wait_for: [odom:1, 2]\n",
                                  PLANT),
    "an empty value": ("robotino_plant:\n  ros__parameters:\n    seed:\n", PLANT),
    "an invalid node name": ("robotino-plant:\n  ros__parameters:\n    seed: 1\n", PLANT),
    "no ros__parameters": ("robotino_plant:\n  seed: 1\n", PLANT),
    "an empty file": ("", PLANT),
    "scalars typed as rcl types them": (
        "camera_driver:\n  ros__parameters:\n" + "".join(f"    k{i}: {s}\n" for i, s in enumerate(SCALARS)),
        "/camera_driver"),
}

# files rcl reads but the package refuses (its own validation), with the words of the one-line error
OWN_REFUSALS = {
    "unknown key": ("robotino_plant:\n  ros__parameters:\n    odometry_noise: {position: 0.001}\n",
                    ["unknown parameter 'odometry_noise.position'", "did you mean 'odometry_noise.position_m'?"]),
    "wrong type": ("/**:\n  ros__parameters:\n    control: {horizon: 4.0}\n", ["control.horizon", "integer"]),
    "out of range": ("/**:\n  ros__parameters:\n    robot: {mass_kg: -1.0}\n", ["robot.mass_kg", "must be >"]),
    "an empty list": ("robotino_plant:\n  ros__parameters:\n    lockstep_wait_for: []\n",
                      ["lockstep_wait_for", "no value"]),
    "a misspelt node": ("robotino_plannt:\n  ros__parameters:\n    seed: 1\n", ["did you mean 'robotino_plant'?"]),
}


def _rcl(files: list[tuple[str, str]]) -> list[dict]:
    """rcl's verdict on each (file, node FQN): {"refused": message} or {"values": {name: [type, value]}}."""
    lines = []
    for path, fqn in files:
        namespace, name = fqn.rsplit("/", 1)
        lines.append(json.dumps([str(path), name, namespace or "/"]))
    run = subprocess.run([sys.executable, "-c", PROBE], input="\n".join(lines) + "\n", capture_output=True, text=True,
                         timeout=300)
    out = [json.loads(line) for line in run.stdout.splitlines() if line.startswith("{")]
    assert len(out) == len(files), run.stderr[-3000:]
    return out


def _plain(value):
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    return [_plain(v) for v in value] if isinstance(value, list) else value


def _typed(value) -> list:
    if value is NO_VALUE:
        return ["NOT_SET", None]
    if isinstance(value, list):
        return [_KIND[type(value[0])] + "_ARRAY", _plain(value)]
    return [_KIND[type(value)], _plain(value)]


def _values_for(path, fqn: str) -> dict:
    """The pre-check's reading of the file for node `fqn`: its sections in order, where rclpy's pattern matches."""
    values = {}
    for section, section_values in parse_parameter_file(path).items():
        pattern = (section if section.startswith("/") else "/" + section).replace("/*", r"(/\w+)")
        if re.fullmatch(pattern, fqn):
            values.update({name: _typed(v) for name, v in section_values.items()})
    return values


@pytest.fixture(scope="module")
def verdicts(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rcl_files")
    paths = {}
    for i, (case, (text, _)) in enumerate({**CASES, **{k: (t, PLANT) for k, (t, _) in OWN_REFUSALS.items()}}.items()):
        paths[case] = folder / f"case{i}.yaml"
        paths[case].write_text(text)
    fqns = {case: CASES[case][1] if case in CASES else PLANT for case in paths}
    return paths, dict(zip(paths, _rcl([(paths[c], fqns[c]) for c in paths])))


@pytest.mark.parametrize("case", list(CASES))
def test_the_pre_check_and_rcl_agree_on_refusal_and_values(verdicts, case):
    paths, rcl = verdicts
    path, (_, fqn) = paths[case], CASES[case]
    try:
        check_parameter_files([path])
        refused = None
    except ParamError as exc:
        refused = str(exc)
    assert (refused is None) == ("values" in rcl[case]), (case, refused, rcl[case])
    if refused is not None:
        assert str(path) in refused and "\n" not in refused
        return
    assert _values_for(path, fqn) == rcl[case]["values"], case


def test_the_cases_cover_what_they_name(verdicts):
    """Each form is there and rcl reads it as named: a tuple as a string array, the alias and the broken
    files refused, the scalars differently typed than YAML 1.1 would (so the test could fail).
    """
    _, rcl = verdicts
    plant = rcl["launch_ros python tuple"]["values"]
    assert plant["lockstep_wait_for"] == ["STRING_ARRAY", ["odom:2", "/clock:2", "reference_preview:2"]]
    assert plant["frame_prefix"] == ["STRING", ""]
    refused = {case for case, verdict in rcl.items() if "refused" in verdict and case in CASES}
    assert refused == {"an alias", "a YAML error", "a sequence of mixed types", "an empty value",
                       "an invalid node name", "no ros__parameters"}
    scalars = rcl["scalars typed as rcl types them"]["values"]
    typed = {s: scalars[f"k{i}"] for i, s in enumerate(SCALARS) if f"k{i}" in scalars}
    assert typed["010"] == ["INTEGER", 8] and typed["08"] == ["DOUBLE", 8.0] and typed["nan"][0] == "DOUBLE"
    assert typed["~"] == ["STRING", "~"] and typed["1_000"] == ["STRING", "1_000"] and typed["y"] == ["BOOL", True]
    assert typed["!!float 1"] == ["INTEGER", 1] and typed["1e400"] == ["STRING", "1e400"]
    assert typed["[]"] == ["NOT_SET", None] and scalars["k36.a.b"] == ["INTEGER", 2]
    wild = rcl["wildcards"]["values"]
    assert wild == {"seed": ["INTEGER", 6], "duration_s": ["DOUBLE", 2.0]}  # '/*' is the root namespace only
    assert rcl["keys with and without a leading slash"]["values"]["seed"] == ["INTEGER", 2]  # the later one
    assert rcl["nested namespace, another robot"]["values"] == {}


@pytest.mark.parametrize("case", list(OWN_REFUSALS))
def test_the_package_refuses_what_rcl_reads_but_its_nodes_cannot_run(verdicts, case):
    paths, rcl = verdicts
    assert "values" in rcl[case], rcl[case]  # rcl reads it: the refusal is the package's
    with pytest.raises(ParamError) as info:
        check_parameter_files([default_params_file(), paths[case]])
    message = str(info.value)
    assert str(paths[case]) in message and "\n" not in message
    for words in OWN_REFUSALS[case][1]:
        assert words in message, message


def test_the_files_a_real_launch_wrote_are_read_alike_by_rcl_and_the_pre_check():
    """The files launch_ros 0.26.6 wrote in two real launches (test/data/launch_ros): each node's own file with
    the preset passes the pre-check, and rcl gives the node the values the pre-check read.
    """
    files = sorted((Path(__file__).resolve().parent / "data" / "launch_ros").glob("*/*.yaml"))
    cases = []
    for path in files:
        (section,) = parse_parameter_file(path)
        namespace = "/robot1" if path.parent.name.startswith("robot1") else ""
        name = {"plant_node": "robotino_plant", "controller_node": "robotino_controller", "recorder_node": "recorder",
                "trajectory_node": "robotino_trajectory"}.get(path.stem, path.stem)
        cases.append((path, f"{namespace}/{name}"))
        assert section in ("/**", f"{namespace}/{name}"), path
        check_parameter_files([default_params_file(), path])
    for (path, fqn), verdict in zip(cases, _rcl(cases)):
        assert verdict.get("values") == _values_for(path, fqn), path
    assert len(cases) == 10
