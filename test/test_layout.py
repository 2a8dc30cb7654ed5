"""The layout's rules that import-linter cannot check: which modules load rclpy when imported (import-linter
sees every import, also those inside functions), the nodes start without pip-only solvers; and
the import-linter contracts (`.importlinter`: the plain core, the layers) hold and can fail.
"""

from __future__ import annotations

import pytest
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import robotino_geom_mpc
import robotino_sim_node

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
# the modules that may import rclpy when imported: the nodes, the recorder node and the ROS plumbing subpackage
# (the plant node's mixins plant_lockstep / plant_network / plant_plans and its radio are ROS adapters too)
ALLOWED_PREFIXES = ("robotino_geom_mpc.nodes.", "robotino_geom_mpc.ros.", "robotino_geom_mpc.recording.recorder_node",
                    "robotino_geom_mpc.recording.live_view_node", "robotino_sim_node.plant_", "robotino_sim_node.radio",
                    "robotino_sim_node.lockstep_start", "robotino_sim_node.outputs", "robotino_sim_node.chain_driver")
# modules of ros/ that load no ROS at import (the report reads bags with them): the CDR readers, decoded values
PLAIN_ROS_MODULES = ("robotino_geom_mpc.ros.cdr", "robotino_geom_mpc.ros.decode")


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
    node = "robotino_geom_mpc.nodes.controller_node"
    assert _imports_rclpy([node]) == {node: True}


def _lint_imports(config: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(Path(sys.executable).with_name("lint-imports")), "--config", str(config)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


def test_the_import_contracts_hold_and_can_fail(tmp_path):
    kept = _lint_imports(ROOT / ".importlinter")
    assert kept.returncode == 0 and "0 broken" in kept.stdout, kept.stdout + kept.stderr
    # the same tool on a contract the code breaks (the nodes import rclpy) reports it
    broken = tmp_path / "broken.ini"
    broken.write_text("[importlinter]\nroot_packages =\n    robotino_geom_mpc\ninclude_external_packages = True\n\n"
                      "[importlinter:contract:nodes-plain]\nname = nodes without rclpy\ntype = forbidden\n"
                      "source_modules =\n    robotino_geom_mpc.nodes\nforbidden_modules =\n    rclpy\n")
    result = _lint_imports(broken)
    assert result.returncode == 1 and "1 broken" in result.stdout and "robotino_geom_mpc.nodes" in result.stdout


def test_the_nodes_import_no_pip_only_solver():
    """daqp (the constrained mode) and osqp (the benchmarks) have no rosdep key: a ROS install via rosdep
    lacks them, so no node may import them at start; the constrained mode imports daqp when built.
    """
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
