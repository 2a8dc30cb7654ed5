"""The layout's rules: the math core is plain numpy/scipy, only nodes and ROS plumbing import rclpy, files stay short."""

from __future__ import annotations

import ast
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import robotino_geom_mpc
import robotino_sim_node

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 450
# the modules that may import rclpy when imported: the nodes, the recorder node and the ROS plumbing subpackage
ALLOWED_PREFIXES = ("robotino_geom_mpc.nodes.", "robotino_geom_mpc.ros.", "robotino_geom_mpc.recording.recorder_node",
                    "robotino_sim_node.plant_node", "robotino_sim_node.lockstep_start",
                    "robotino_sim_node.outputs")
# modules of ros/ that need no ROS at all (decoders of message values, the process launcher, the SHM cleaner)
PLAIN_ROS_MODULES = ("robotino_geom_mpc.ros.decode", "robotino_geom_mpc.system.processes", "robotino_geom_mpc.system.shm")


def _modules() -> list[str]:
    names = []
    for package in (robotino_geom_mpc, robotino_sim_node):
        names.append(package.__name__)
        names += [m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + ".")
                  if not m.name.endswith(".__main__")]  # running it is the command line
    return sorted(names)


def _imports_rclpy(modules: list[str]) -> dict[str, bool]:
    """Per module, whether importing it alone (in a fresh interpreter) loads rclpy."""
    script = (
        "import importlib, json, sys\n"
        "importlib.import_module(sys.argv[1])\n"
        "print(json.dumps('rclpy' in sys.modules))\n"
    )
    out = {}
    for name in modules:
        proc = subprocess.run([sys.executable, "-c", script, name], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, f"import {name} failed:\n{proc.stderr}"
        out[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def test_only_nodes_and_ros_plumbing_import_rclpy():
    candidates = [m for m in _modules() if not m.startswith(ALLOWED_PREFIXES)] + list(PLAIN_ROS_MODULES)
    # one interpreter for all first (cheap); name the culprits one by one only when it fails
    script = "import importlib, sys\nfor m in sys.argv[1:]: importlib.import_module(m)\nprint('rclpy' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", script, *candidates], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    if proc.stdout.strip().splitlines()[-1] == "True":
        culprits = [name for name, loads in _imports_rclpy(candidates).items() if loads]
        raise AssertionError(f"these modules import rclpy at import time: {culprits}")
    # and the check can fail: a node module does load it
    assert _imports_rclpy(["robotino_geom_mpc.nodes.controller_node"]) == {"robotino_geom_mpc.nodes.controller_node": True}


CORE = ("errors", "arrays", "scenarios", "params", "model", "geometric", "control", "reference", "network")


def test_the_math_core_never_imports_ros():
    pkg = ROOT / "robotino_geom_mpc"
    paths = [p for name in CORE for p in ([pkg / f"{name}.py"] if (pkg / f"{name}.py").exists()
                                           else sorted((pkg / name).glob("*.py")))]
    offenders = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            offenders += [f"{path.name}: {n}" for n in names
                          if n.split(".")[0] in ("rclpy", "rosbags", "mcap", "mcap_ros2", "robotino_sim_node")
                          or n.split(".")[0].endswith("_msgs") or n.startswith("robotino_geom_mpc.")
                          and n.split(".")[1] not in CORE]
    assert len(paths) > 20 and offenders == []


def test_no_package_file_over_the_line_limit():
    files = sorted((ROOT / "robotino_geom_mpc").rglob("*.py")) + sorted((ROOT / "robotino_sim_node").rglob("*.py"))
    long = {str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}


def test_the_nodes_import_no_pip_only_solver():
    """daqp (the constrained mode) and osqp (the benchmarks) have no rosdep key: a ROS install via rosdep
    lacks them, so no node may import them at start; the constrained mode imports daqp when built."""
    nodes = ["robotino_sim_node.plant_node", "robotino_geom_mpc.nodes.trajectory_node",
             "robotino_geom_mpc.nodes.controller_node", "robotino_geom_mpc.nodes.robot_description_node",
             "robotino_geom_mpc.nodes.goal_sender", "robotino_geom_mpc.recording.recorder_node"]
    script = ("import importlib, sys\nfor m in sys.argv[1:]: importlib.import_module(m)\n"
              "print(sorted(m for m in ('daqp', 'osqp') if m in sys.modules))\n"
              "from robotino_geom_mpc.control.motion_controller import MotionController\n"
              "from robotino_geom_mpc.params.files import load_params\n"
              "from dataclasses import replace\n"
              "robot, control = load_params()\n"
              "MotionController(robot, replace(control, mode='constrained'))\n"
              "print('daqp' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", script, *nodes], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["[]", "True"]
