"""The layout's rules that import-linter cannot check: which modules load rclpy when imported (import-linter
sees every import, also those inside functions), the nodes start without pip-only solvers; the import-linter
contracts (`.importlinter`: the plain core, the layers) hold and can fail; and the node modules that run the loops
hold no control decisions (no arithmetic on stamps or states, lockstep chosen at construction), and that check can
fail. Sizes are the concepts' (no line cap): the layers and these checks are what the cap stood in for.
"""

from __future__ import annotations

import ast
import json
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

import robotino_geom_mpc
import robotino_sim_node

ROOT = Path(__file__).resolve().parents[1]
# the modules that may import rclpy when imported: the nodes, the recorder node and the ROS plumbing subpackage
# (the plant node's runs plant_lockstep / plant_realtime / chain_driver, plant_plans, plant_run and its radio are ROS
# adapters too)
ALLOWED_PREFIXES = ("robotino_geom_mpc.nodes.", "robotino_geom_mpc.ros.", "robotino_geom_mpc.recording.recorder_node",
                    "robotino_geom_mpc.recording.live_view_node", "robotino_sim_node.plant_", "robotino_sim_node.radio",
                    "robotino_sim_node.lockstep_start", "robotino_sim_node.outputs", "robotino_sim_node.chain_driver",
                    "robotino_sim_node.fleet_plant_node")
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


@pytest.mark.ros
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


@pytest.mark.ros
def test_every_public_error_of_the_package_is_a_robotino_error():
    """errors.py's promise: a caller catches all of the package's errors with `RobotinoError` (each module's
    exception classes, imported in a fresh interpreter; private ones, leading underscore, are internal flow).
    """
    script = (
        "import importlib, inspect, json, sys\n"
        "from robotino_geom_mpc.errors import RobotinoError\n"
        "found, bad = [], []\n"
        "for m in sys.argv[1:]:\n"
        "    module = importlib.import_module(m)\n"
        "    for name, cls in vars(module).items():\n"
        "        if inspect.isclass(cls) and issubclass(cls, BaseException) and cls.__module__ == m \\\n"
        "                and not name.startswith('_'):\n"
        "            found.append(f'{m}.{name}')\n"
        "            if not issubclass(cls, RobotinoError):\n"
        "                bad.append(f'{m}.{name}')\n"
        "print(json.dumps([found, bad]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script, *_modules()], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    found, bad = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "robotino_geom_mpc.params.specs.ParamError" in found and len(found) > 20  # the walk saw the package
    assert bad == [], f"exception classes not derived from RobotinoError: {bad}"


def _lint_imports(config: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(Path(sys.executable).with_name("lint-imports")), "--config", str(config)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.ros
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


@pytest.mark.ros
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


# -- the node modules hold no control decisions (issue 37, item 5) ---------------------------------------------------
# The node modules are adapters: messages decoded -> a loop (`robotino_geom_mpc.loop`) -> messages published, timers.
# Every module of robotino_geom_mpc/nodes and robotino_sim_node is checked but these (they run no loop), with why:
NOT_LOOP_ADAPTERS = {
    "robotino_geom_mpc/nodes/__init__.py": "the package",
    "robotino_sim_node/__init__.py": "the package",
    "robotino_geom_mpc/nodes/goal_sender.py": "a goal file sent on the node clock (no loop)",
    "robotino_geom_mpc/nodes/robot_description_node.py": "the URDF and the wheels' joint states (no loop)",
    "robotino_sim_node/loop_timing.py": "the run's timing statistics on the steady clock: measures the host",
    "robotino_sim_node/lockstep_start.py": "the start handshake: the graph's endpoints over the steady clock",
}
# What a stamp or a state is called: message stamps and clock readings in ns, the robot's state, pose, twist,
# heading, command values, voltages, currents (lower case: UPPER_CASE names are constants such as CDR field lists).
STAMP_OR_STATE = re.compile(r"stamp|_ns$|^ns$|nanoseconds|state|pose|twist|theta|^X$|^values$|voltages|currents|"
                            r"velocit")
NS_PER_S = (1e9, 1e-9)  # a conversion between seconds and nanoseconds is stamp arithmetic whatever the names
ARITHMETIC = (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.FloorDiv, ast.Mod, ast.Pow, ast.MatMult)  # not | (type unions)
ORDERING = (ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.Eq, ast.NotEq)  # not is / in (None checks, membership)
# calls whose result is their arguments' value (a method call's is the callee's business)
VALUE_CALLS = {"len", "sum", "abs", "min", "max", "int", "float", "round", "tuple", "list"}
# (module, function, expression) -> why this arithmetic on a matching name is wiring, not a control decision
WIRING = {
    ("robotino_geom_mpc/nodes/controller_inputs.py", "closed_loop_problem", "values[name] < 2.0 * period"):
        "a parameter set's validation: the timeouts' values against two control periods (parameters, not states)",
    ("robotino_sim_node/plant_lockstep.py", "_period", "delay * 1000000000.0"):
        "the pace timer's period [ns] from the wall-clock delay `LockstepPace` decided (a timer, not a stamp)",
}
# where a node may look at the mode: while it is built (the loop's pairing, the run object, QoS and publishers), and
# when a parameter set is validated (a realtime-only feature refused in lockstep)
CONSTRUCTION = {"__init__", "chain_of", "_params_problem"}
# the node modules that run no loop but choose the mode once too (checked for that only)
MODE_ONLY = ("robotino_geom_mpc/nodes/goal_sender.py", "robotino_geom_mpc/nodes/robot_description_node.py")


def _subjects(expr: ast.AST) -> set[str]:
    """The names whose value an operand is: a name, an attribute chain, a subscript's container, the arguments of a
    value call (len, sum, math.*, ...); of a method call only its receiver (the callee decides, not the node).
    """
    if isinstance(expr, ast.Name):
        return {expr.id}
    if isinstance(expr, ast.Attribute):
        return {expr.attr} | _subjects(expr.value)
    if isinstance(expr, ast.Subscript):
        return _subjects(expr.value)
    if isinstance(expr, (ast.BinOp, ast.UnaryOp)):
        return set().union(*(_subjects(c) for c in ast.iter_child_nodes(expr)))
    if isinstance(expr, ast.Call):
        func = expr.func
        module_function = isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name) and \
            func.value.id in ("math", "np")
        if module_function or (isinstance(func, ast.Name) and func.id in VALUE_CALLS):
            return set().union(set(), *(_subjects(a) for a in expr.args))
        return _subjects(func.value) if isinstance(func, ast.Attribute) else set()
    return set()


def _operands(node: ast.AST) -> list[ast.expr]:
    if isinstance(node, ast.BinOp) and isinstance(node.op, ARITHMETIC):
        return [node.left, node.right]
    if isinstance(node, ast.AugAssign):
        return [node.target, node.value]
    if isinstance(node, ast.Compare) and any(isinstance(op, ORDERING) for op in node.ops):
        return [node.left, *node.comparators]
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        return [node.operand]
    return []


def _functions(tree: ast.AST):
    """(innermost enclosing function's name or '', node) for every node of `tree`."""
    stack: list[tuple[str, ast.AST]] = [("", tree)]
    while stack:
        where, node = stack.pop()
        for child in ast.iter_child_nodes(node):
            inner = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else where
            yield inner, child
            stack.append((inner, child))


def control_decisions(path: str, source: str, wiring: dict | None = None, arithmetic: bool = True) -> list[str]:
    """Arithmetic or ordering on a stamp or a state (or a s <-> ns conversion) outside `wiring` (default `WIRING`;
    not looked for unless `arithmetic`), and a look at the mode (``lockstep``) outside construction, in one node
    module: one line each, ``path:line: code``.
    """
    wiring = WIRING if wiring is None else wiring
    found = []
    for where, node in _functions(ast.parse(source)):
        operands = _operands(node)
        if arithmetic and operands and (path, where, ast.unparse(node)) not in wiring:
            names = set().union(*(_subjects(o) for o in operands))
            constants = {o.value for o in operands if isinstance(o, ast.Constant)}
            if any(STAMP_OR_STATE.search(n) for n in names) or constants & set(NS_PER_S):
                found.append(f"{path}:{node.lineno}: {ast.unparse(node)}")
        mode = (isinstance(node, ast.Name) and node.id == "lockstep") or \
            (isinstance(node, ast.Attribute) and node.attr == "lockstep") or \
            (isinstance(node, ast.Constant) and node.value == "lockstep")
        if mode and where not in CONSTRUCTION and not _in_spec(node, source):
            found.append(f"{path}:{node.lineno}: the mode looked at in {where or 'the module'}()")
    return sorted(set(found))


def _in_spec(node: ast.AST, source: str) -> bool:
    """A ``"lockstep"`` string of a parameter's declaration (its choices), not a branch."""
    return isinstance(node, ast.Constant) and "choices=" in source.splitlines()[node.lineno - 1]


def _loop_adapters() -> list[Path]:
    files = sorted([*ROOT.glob("robotino_geom_mpc/nodes/*.py"), *ROOT.glob("robotino_sim_node/*.py")])
    assert set(NOT_LOOP_ADAPTERS) <= {str(f.relative_to(ROOT)) for f in files}, "a module named here is gone"
    return [f for f in files if str(f.relative_to(ROOT)) not in NOT_LOOP_ADAPTERS]


@pytest.mark.unit
def test_the_node_modules_hold_no_control_decisions():
    adapters = _loop_adapters()
    assert {"controller_node.py", "plant_node.py", "command_buffer_node.py", "chain_driver.py",
            "trajectory_node.py"} <= {f.name for f in adapters}
    found = [line for f in adapters for line in control_decisions(str(f.relative_to(ROOT)), f.read_text())]
    found += [line for path in MODE_ONLY for line in control_decisions(path, (ROOT / path).read_text(),
                                                                      arithmetic=False)]
    assert found == [], "control decisions in node modules (move them into robotino_geom_mpc/loop):\n" + \
        "\n".join(found)
    # every wiring exception is still needed (an exception nothing needs any more is removed, not kept)
    for path, where, code in WIRING:
        assert any(line.endswith(f": {code}") for line in control_decisions(path, (ROOT / path).read_text(), {})), \
            f"{path}: {where}: {code} needs no exception any more"


@pytest.mark.unit
def test_the_control_decision_check_can_fail():
    """Planted decisions are found, line by line; wiring (a timer period, a busy time, a type union, a None check,
    list concatenation of messages, a call handing a stamp to a loop) is not.
    """
    planted = """
class Node:
    def __init__(self, params, lockstep):
        self.timer = create_timer(1.0 / params["rate_hz"])
        self.pick = A if lockstep else B
        self.run: LockstepRun | RealtimeRun
    def _on_odom(self, stamp_ns, msg):
        begin = monotonic()
        if self.last_ns is not None and stamp_ns <= self.last_ns:
            return
        dt = (stamp_ns - self.last_ns) * 1e-9
        self.busy_s += monotonic() - begin
        self.publish(self.outputs.period(msg) + self.outputs.state(msg.stamp_ns))
        self.loop.on_odometry(Odometry(stamp_ns, values), now)
    def _command(self, values):
        if len(values) != 3:
            return
        x = self.state[0] + 0.1
        now_s = self.get_clock().now().nanoseconds * 1e-9
        if self.lockstep:
            self.resend()
"""
    found = control_decisions("planted.py", planted)
    # the stamp compared (9) and differenced into seconds (11), the command's length (16), a state's arithmetic (18),
    # the clock made seconds (19), the mode looked at per call (20); nothing else
    assert {int(line.split(":")[1]) for line in found} == {9, 11, 16, 18, 19, 20}, found
