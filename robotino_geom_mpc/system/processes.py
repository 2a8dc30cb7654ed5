"""Start the nodes as separate processes and stop them cleanly (as `ros2 launch` would; used by `run`, bench, tests).

Each node runs as ``sys.executable -m MODULE --ros-args ...`` in its own
process group with stdout/stderr in files, so a Ctrl-C of the caller does not
reach the nodes directly and every node is stopped in order: SIGINT, then
SIGTERM and SIGKILL after grace periods, nothing left running. Before the SIGKILL a node gets SIGUSR1, on which
a node process prints every thread's stack on stderr (`ros.spin.start_rclpy`): the report of a node that did not
stop says where it hung.
"""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["NODE_MODULES", "FRAME_PREFIX_NODES", "LOCKSTEP_WAIT_FOR", "TIMING_REPORT",
           "RECORDER_WAIT_FOR", "recorder_wait_for", "answer_topic", "command_readers", "scenario_parameters",
           "NamespaceError", "NodeFailed", "NodeProcess", "NodeGroup",
           "dds_environment",
           "wait_for_exit",
           "FLEET_NODES", "FLEET_PREVIEW_EVERY", "fleet_arguments", "fleet_realtime_parameters", "fleet_wait_for",
           "frame_prefix", "namespace_remaps", "node_arguments",
           "robot_names", "ros_args", "ros_namespace"]

from robotino_geom_mpc.errors import RobotinoError
from robotino_geom_mpc.system.shm import remove_zombie_segments
from robotino_geom_mpc.system.signals import NODE_MODULES  # executable name -> module run with `python -m`

# the lockstep plant's ``lockstep_wait_for`` (subscriptions ``topic:count`` it waits for before tick 0):
# the controller's and the trajectory's
LOCKSTEP_WAIT_FOR = ("odom:1", "/clock:1", "reference_preview:1")
# with the recorder too, which subscribes every topic (its /clock subscription is a recording one)
RECORDER_WAIT_FOR = ("odom:2", "/clock:2", "reference_preview:2", "wheel_voltages:2", "ground_truth/odom:1",
                     "wheel_currents:1", "joint_states:1", "diagnostics:1")


def answer_topic(command_interface: str = "voltages", plans: bool = False) -> str:
    """The topic the plant reads the controller's answers on: the command's (``wheel_voltages`` / ``cmd_vel``),
    with `plans` the plan's (``wheel_voltage_plan`` / ``cmd_vel_plan``).
    """
    command = "wheel_voltages" if command_interface == "voltages" else "cmd_vel"
    return f"{command.replace('wheel_voltages', 'wheel_voltage')}_plan" if plans else command


def recorder_wait_for(command_interface: str = "voltages", plans: bool = False) -> list[str]:
    """`RECORDER_WAIT_FOR` for a run's nodes (a description publisher among them) and command interface: with
    ``cmd_vel`` the controller's twist (``cmd_vel:2``, the plant's and the recorder's readers) instead of
    ``wheel_voltages``, and the recorder's reader of the plant's ``applied_voltages``. With `plans` the plant
    reads the plan topic (``wheel_voltage_plan:2`` / ``cmd_vel_plan:2``; the plain command the recorder alone)
    and the controller and the recorder the plant's ``command_applied``.
    """
    # joint_states: the recorder's reader and the description publisher's (its wheel TF recorded from tick 0)
    waits = [w.replace("joint_states:1", "joint_states:2") for w in RECORDER_WAIT_FOR]
    if command_interface != "voltages":
        waits = [w.replace("wheel_voltages:", "cmd_vel:") for w in waits] + ["applied_voltages:1"]
    if plans:
        command = answer_topic(command_interface)
        waits = [f"{command}:1" if w == f"{command}:2" else w for w in waits]
        waits += [f"{answer_topic(command_interface, plans)}:2", "command_applied:2"]
    return waits


def command_readers(wait_for: Iterable[str], command_interface: str = "voltages", plans: bool = False) -> int:
    """The controller's ``lockstep_command_readers``: the count of the topic the plant reads its answers on (the
    command's, ``wheel_voltages`` / ``cmd_vel``; with `plans` the plan's) in the plant's ``lockstep_wait_for``
    `wait_for`, or 1 (the plant's reader) where it names none.
    """
    topic = answer_topic(command_interface, plans)
    counts = [int(count) for name, _, count in (entry.rpartition(":") for entry in wait_for) if name == topic]
    return counts[0] if counts else 1


FASTDDS_PROFILE = "fastdds_localhost.xml"  # in config/: the nodes' profile on one host (`dds_environment`)
# the lockstep plant's ``lockstep_settle_s`` when the nodes get that profile (`dds_environment`): one of its 0.1 s
# participant announcement periods, in which an announcement lost at the start is repeated (the plant's default,
# 1 s, is for any DDS setup). It was 0.4 s; with a settle of 1 ms, 21 runs (15 beside a busy core) each recorded
# every message of every loop topic from tick 0 (test_lossless_recording counts a run's bag)
PROFILE_SETTLE_S = 0.1

# the nodes that declare ``frame_prefix`` (their frame ids: odometry, /tf, paths)
TIMING_REPORT = "plant_timing.json"  # in a run's log directory: the plant's timing report (loop_timing)
FRAME_PREFIX_NODES = ("plant_node", "controller_node", "trajectory_node", "robot_description_publisher")
_NAMESPACE_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class NamespaceError(RobotinoError, ValueError):
    """A robot namespace that is not a valid ROS namespace."""


def ros_namespace(namespace: str) -> str:
    """`namespace` as an absolute ROS namespace (``robot1`` -> ``/robot1``; ``""`` or ``/`` -> ``""``: none).

    Raises
    ------
    NamespaceError
        If a token is not a valid ROS name (letters, digits, underscores; not starting with a digit).
    """
    tokens = namespace.strip().strip("/").split("/")
    if tokens == [""]:
        return ""
    bad = [t for t in tokens if not _NAMESPACE_TOKEN.fullmatch(t)]
    if bad:
        raise NamespaceError(f"namespace {namespace!r}: {bad[0]!r} is not a valid ROS name "
                             "(letters, digits and underscores, not starting with a digit)")
    return "/" + "/".join(tokens)


def frame_prefix(namespace: str) -> str:
    """The frame prefix of a robot in `namespace` (`ros_namespace`): ``/robot1`` -> ``robot1/``; none -> ``""``.

    Frames stay apart on the global ``/tf`` this way, as robot_state_publisher's ``frame_prefix`` does it.
    """
    namespace = ros_namespace(namespace)
    return namespace[1:] + "/" if namespace else ""


def namespace_remaps(namespace: str, lockstep: bool) -> dict[str, str]:
    """The remappings (``from -> to``) that put a run's nodes in `namespace` (`ros_namespace`; none for ``""``).

    Every topic of the nodes is relative and moves with ``__ns``. The lockstep plant's ``/clock`` is global
    by convention; with a namespace it becomes ``<namespace>/clock``, so robots in lockstep in one domain
    each keep their own time.
    """
    namespace = ros_namespace(namespace)
    if not namespace:
        return {}
    return {"__ns": namespace, **({"/clock": f"{namespace}/clock"} if lockstep else {})}


def scenario_parameters(scenario: str, robot: Any, control: Any, link: Any = None,
                        plans: bool | None = None) -> tuple[dict[str, dict[str, Any]], bool]:
    """The nodes' parameter overrides of `scenario` (`scenarios.node_parameters`) and whether they run plans.

    `link` (`network.link.LinkParams`, each way) replaces the scenario's own link; `plans` (None: whenever there
    is a link) makes the controller send delay-compensated plans and the plant take them (``plans`` of both; the
    trajectory's ``preview_points`` the plans' `DelayCompensatingController.preview_length`), as `simulate` does.
    """
    from robotino_geom_mpc.scenarios import node_parameters

    overrides = node_parameters(scenario, robot)
    if link is not None:
        overrides["plant_node"].update(
            {f"link.{way}.{name}": float(value) for way in ("up", "down") for name, value in vars(link).items()})
    networked = any(name.startswith("link.") and name.rsplit(".", 1)[1] != "burst_length" and value
                    for name, value in overrides["plant_node"].items())
    plans = networked if plans is None else plans
    if plans:
        from robotino_geom_mpc.control.delay_compensation import DelayCompensatingController

        overrides["plant_node"]["plans"] = overrides["controller_node"]["plans"] = True
        overrides["trajectory_node"]["preview_points"] = DelayCompensatingController(robot, control).preview_length
    return overrides, plans


def node_arguments(
    scenario: str,
    params_file: str | os.PathLike,
    duration_s: float,
    lockstep: bool,
    seed: int = 0,
    bag: str | os.PathLike | None = None,
    wait_for: list[str] | None = None,
    overrides: dict[str, dict[str, Any]] | None = None,
    odometry: str = "ideal",
    namespace: str = "",
    goals_file: str | os.PathLike | None = None,
    command_interface: str = "voltages",
    environ: Mapping[str, str] | None = None,
    link: Any = None,
    plans: bool | None = None,
    live_view_port: int | None = None,
) -> dict[str, list[str]]:
    """The ``--ros-args`` of each node of a run (executable name -> arguments), recorder first when `bag`.

    Each node gets the parameter file, the scenario's overrides (`scenarios.node_parameters`) and the
    mode; the plant the run's length, the seed, ``odometry_model`` (`odometry`: ideal or encoders; with
    encoders the controller ``control.odometry_twist: period_mean``) and
    ``lockstep_wait_for`` (`wait_for`, by default the subscriptions of the nodes started:
    `LOCKSTEP_WAIT_FOR`, or `recorder_wait_for(command_interface)` with a recorder), and the lockstep
    controller the readers of its command among them (``lockstep_command_readers``, `command_readers`);
    `overrides` (per executable name) come last. A `namespace` moves every node into it (`namespace_remaps`)
    and gives the nodes of `FRAME_PREFIX_NODES` its `frame_prefix`.
    A ``robot_description_publisher`` publishes the URDF and the wheels' TF (lossless in lockstep, its ``mode``).
    `command_interface`
    cmd_vel goes to the controller and the plant (voltages, their default, is left to them).
    With `goals_file` (scenario ``goals``) a ``goal_sender`` sends the file's
    goals and paths; a lockstep plant waits for its odom subscription too, so its times count from tick 0.
    `environ` is the environment the nodes will run in (`os.environ` if None, as for a `NodeGroup` without
    ``env``): where `dds_environment` gives them the package's profile, a lockstep plant settles
    `PROFILE_SETTLE_S` before tick 0 instead of its default.
    `link` (`network.link.LinkParams`, each way) puts the plant's emulated radio link between the robot and the
    other nodes (over the scenario's own link, e.g. ``wifi``'s); `plans` as `scenario_parameters` takes them:
    False over a link is the uncompensated baseline (plain commands acting on arrival).
    With `live_view_port` a ``live_view_node`` serves every topic there (Foxglove WebSocket); a lockstep plant
    waits for its subscriptions too (one more on each topic it waits for) and runs at real time at most
    (``lockstep_max_realtime_factor`` 1), so the view shows the run from tick 0 at the pace it would have.
    """
    from robotino_geom_mpc.params.files import load_params
    from robotino_geom_mpc.params.specs import RECORDED_CONTROLLER_SPECS
    from robotino_geom_mpc.model.encoders import CONTROLLER_TWIST

    robot, control = load_params(params_file)
    mode = "lockstep" if lockstep else "realtime"
    scenario_overrides, plans = scenario_parameters(scenario, robot, control, link, plans)
    extra = overrides or {}
    if wait_for is None:
        wait_for = list(LOCKSTEP_WAIT_FOR) if bag is None else recorder_wait_for(command_interface, plans)
        if goals_file is not None:  # the goal sender's odom subscription (its clock) too
            wait_for = [f"odom:{int(w.split(':')[1]) + 1}" if w.startswith("odom:") else w for w in wait_for]
        if live_view_port is not None:  # the live view subscribes every topic
            wait_for = [f"{topic}:{int(count) + 1}" for topic, _, count in (w.rpartition(":") for w in wait_for)]
    remaps = namespace_remaps(namespace, lockstep)
    frames = {name: {"frame_prefix": frame_prefix(namespace)} for name in FRAME_PREFIX_NODES} if namespace else {}
    args = {}
    if bag is not None:  # it stores the controller's chain and loop settings given here (for the replays)
        settings = {name: value for name, value in {**scenario_overrides["controller_node"],
                                                    **extra.get("controller_node", {})}.items()
                    if name in {spec.name for spec in RECORDED_CONTROLLER_SPECS}}
        args["recorder_node"] = ros_args(params_file, {"output": str(bag), "scenario": scenario, **settings,
                                                       **extra.get("recorder_node", {})}, remaps)
    # no use_sim_time: in lockstep the trajectory's time is the /clock messages and the controller's the
    # odometry stamps; the time source's /clock reader would cost each a wake-up a tick
    twist = {"controller_node": {"control.odometry_twist": CONTROLLER_TWIST[odometry]}} \
        if odometry in CONTROLLER_TWIST else {}
    interface: dict[str, dict[str, Any]] = {} if command_interface == "voltages" else {
        name: {"command_interface": command_interface} for name in ("controller_node", "plant_node")}
    if lockstep:  # the command's readers the plant waits for, matched by the controller's writer too
        interface.setdefault("controller_node", {})["lockstep_command_readers"] = command_readers(
            extra.get("plant_node", {}).get("lockstep_wait_for", wait_for), command_interface, plans)
    for name in ("trajectory_node", "controller_node"):
        args[name] = ros_args(params_file, {**scenario_overrides[name], "mode": mode, **twist.get(name, {}),
                                            **interface.get(name, {}), **frames.get(name, {}), **extra.get(name, {})},
                              remaps)
    own_profile = dds_environment(os.environ if environ is None else environ)
    settle = {"lockstep_settle_s": PROFILE_SETTLE_S} if lockstep and own_profile else {}
    if lockstep and live_view_port is not None:
        settle["lockstep_max_realtime_factor"] = 1.0
    args["plant_node"] = ros_args(params_file, {
        **scenario_overrides["plant_node"],
        "mode": mode,
        **settle,
        "duration_s": float(duration_s),
        "seed": int(seed),
        "odometry_model": odometry,
        **interface.get("plant_node", {}),
        "lockstep_wait_for": list(wait_for),
        **frames.get("plant_node", {}),
        **extra.get("plant_node", {}),
    }, remaps)
    # the URDF on robot_description and the wheels' TF, from the same robot parameters as the plant
    args["robot_description_publisher"] = ros_args(params_file, {
        "mode": mode, **({"frame_prefix": frame_prefix(namespace)} if namespace else {}),
        **extra.get("robot_description_publisher", {})}, remaps)
    if goals_file is not None:
        args["goal_sender"] = ros_args(None, {"goals_file": str(goals_file), "mode": mode}, remaps)
    if live_view_port is not None:
        args["live_view_node"] = ros_args(None, {"port": int(live_view_port), **extra.get("live_view_node", {})},
                                          remaps)
    return args


# a fleet's processes (one node per robot in each, `ros.fleet`): the single-robot node -> the fleet's executable
FLEET_NODES = {"recorder_node": "recorder_node", "trajectory_node": "fleet_trajectory_node",
               "controller_node": "fleet_controller_node", "plant_node": "fleet_plant_node"}


FLEET_PREVIEW_EVERY = 10  # a realtime fleet's trajectory nodes publish a preview every this many control periods


def fleet_realtime_parameters(period_s: float) -> dict[str, dict[str, Any]]:
    """A realtime fleet's parameters (single node's executable -> parameters): every robot's preview every
    `FLEET_PREVIEW_EVERY` control periods (``preview_every``: a message of N robots' per tick less for the fleet's
    processes and its recorder, each preview covering the periods until the next), and its controller's
    ``reference_timeout_s`` the default's over that period.
    """
    from robotino_geom_mpc.loop.controller_loop import LoopSettings

    timeout_s = LoopSettings().reference_timeout_s + FLEET_PREVIEW_EVERY * period_s
    return {"trajectory_node": {"preview_every": FLEET_PREVIEW_EVERY},
            "controller_node": {"reference_timeout_s": round(timeout_s, 9)}}


def robot_names(count: int) -> list[str]:
    """The namespaces of a fleet of `count` robots: ``robot1`` .. ``robot<count>``."""
    return [f"robot{k}" for k in range(1, count + 1)]


def fleet_wait_for(robots: int, record: bool, command_interface: str = "voltages") -> list[str]:
    """A fleet plant's ``lockstep_wait_for`` (each robot's): the loop's subscriptions in its namespace (with the
    recorder's: `recorder_wait_for`, no description publisher and no joint_states: the fleet plant's default),
    and on the fleet's one /clock every robot's trajectory node (and the recorder).
    """
    waits = [w for w in recorder_wait_for(command_interface) if not w.startswith("joint_states:")] if record \
        else list(LOCKSTEP_WAIT_FOR)
    clock_readers = robots + (1 if record else 0)
    return [f"/clock:{clock_readers}" if w.startswith("/clock:") else w for w in waits]


def fleet_arguments(scenario: str, params_file: str | os.PathLike, duration_s: float, lockstep: bool, robots: int,
                    seed: int = 0, bag: str | os.PathLike | None = None, odometry: str = "ideal",
                    command_interface: str = "voltages", overrides: dict[str, dict[str, Any]] | None = None,
                    environ: Mapping[str, str] | None = None) -> dict[str, list[str]]:
    """The ``--ros-args`` of a fleet's processes (`FLEET_NODES`: executable -> arguments), recorder first when `bag`.

    `robots` robots ``robot1`` .. ``robot<robots>``, each with the nodes' arguments of a single robot's run
    (`node_arguments`: the scenario, the mode, the seed, ...; `overrides` by the single node's executable name),
    as ``robots`` of each fleet process; the recorder at the root records them all. A lockstep plant waits as
    `fleet_wait_for` says; no robot description publisher. Realtime: `fleet_realtime_parameters` under `overrides`.
    """
    from robotino_geom_mpc.params.files import load_params

    if not lockstep:
        realtime = fleet_realtime_parameters(load_params(params_file)[1].period_s)
        overrides = {name: {**realtime.get(name, {}), **(overrides or {}).get(name, {})}
                     for name in {*realtime, *(overrides or {})}}
    single = node_arguments(scenario, params_file, duration_s, lockstep, seed, bag,
                            wait_for=fleet_wait_for(robots, bag is not None, command_interface),
                            overrides=overrides, odometry=odometry, command_interface=command_interface,
                            environ=environ)
    fleet = ["-p", f"robots:={_format(robot_names(robots))}"]
    return {FLEET_NODES[name]: argv + ([] if name == "recorder_node" else fleet) for name, argv in single.items()
            if name in FLEET_NODES}


def dds_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """DDS settings to add to `environ` for the nodes: config/fastdds_localhost.xml unless the user names a profile.

    That Fast DDS profile announces each participant every 0.1 s instead of 3 s (and sends heartbeats every
    0.1 s): a participant that starts after another's initial announcements is otherwise often matched only at
    that one's next periodic announcement. It keeps the default transports, so it suits every discovery range
    on one host (`ros2 launch` gives the nodes the same file); across hosts use config/fastdds_udp.xml. Nothing
    is added when `FASTRTPS_DEFAULT_PROFILES_FILE` is set already.
    """
    from robotino_geom_mpc.params.presets import config_file

    if "FASTRTPS_DEFAULT_PROFILES_FILE" in environ:
        return {}
    return {"FASTRTPS_DEFAULT_PROFILES_FILE": str(config_file(FASTDDS_PROFILE))}


class NodeFailed(RobotinoError, RuntimeError):
    """A node process exited with a non-zero status; the message names it and quotes its stderr tail."""


def _format(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, tuple)):  # a YAML flow sequence; strings quoted
        return "[" + ",".join(json.dumps(v) if isinstance(v, str) else _format(v) for v in value) + "]"
    return str(value)


def ros_args(params_file: str | os.PathLike | None = None, overrides: dict[str, Any] | None = None,
             remaps: dict[str, str] | None = None) -> list[str]:
    """``--ros-args [--params-file F] -p name:=value ... -r from:=to ...`` (overrides win over the file, as in rcl)."""
    args = ["--ros-args"]
    if params_file is not None:
        args += ["--params-file", str(params_file)]
    for name, value in (overrides or {}).items():
        args += ["-p", f"{name}:={_format(value)}"]
    for source, target in (remaps or {}).items():
        args += ["-r", f"{source}:={target}"]
    return args


def wait_for_exit(popens: list[subprocess.Popen], timeout_s: float) -> None:
    """Block until one of `popens` exits or `timeout_s` passes (Linux: on pidfds, woken at the exit itself;
    elsewhere a 20 ms poll). Reaps nothing: `Popen.poll` then tells which one ended.
    """
    running = [p for p in popens if p.poll() is None]
    if not running or timeout_s <= 0.0:
        return
    if not hasattr(os, "pidfd_open"):
        time.sleep(min(timeout_s, 0.02))
        return
    fds = [os.pidfd_open(p.pid) for p in running]  # not reaped yet: the pids are still these processes'
    try:
        select.select(fds, [], [], timeout_s)
    finally:
        for fd in fds:
            os.close(fd)


STACKS_WAIT_S = 0.5  # how long a node that is about to be killed gets to print its stacks (SIGUSR1)


def _print_stacks(nodes: list[NodeProcess]) -> None:
    """SIGUSR1 to each of `nodes` (a node process prints its threads' stacks on stderr), then wait `STACKS_WAIT_S`."""
    for node in nodes:
        try:
            os.killpg(node.popen.pid, signal.SIGUSR1)
        except ProcessLookupError:
            pass
    time.sleep(STACKS_WAIT_S)


@dataclass
class NodeProcess:
    """One running node: its name, the Popen, and the files holding its output."""

    name: str
    popen: subprocess.Popen
    stdout_path: Path
    stderr_path: Path

    def stderr_tail(self, lines: int = 15) -> str:
        """The last lines of the node's stderr (and stdout, where rclpy logs go)."""
        text = []
        for path in (self.stdout_path, self.stderr_path):
            try:
                text += path.read_text(errors="replace").splitlines()
            except OSError:
                pass
        return "\n".join(text[-lines:])


@dataclass
class NodeGroup:
    """The processes of one run; a context manager that always stops them all.

    Parameters
    ----------
    log_dir
        Where each node's stdout/stderr go (a temporary directory if None).
    env
        Extra environment variables for the nodes.
    prefix
        A command the nodes run under (e.g. ``("ip", "netns", "exec", "ns1")``: in a network namespace); it must
        exec the node, so that signals reach it.
    """

    log_dir: Path | None = None
    env: dict[str, str] = field(default_factory=dict)
    prefix: tuple[str, ...] = ()
    nodes: list[NodeProcess] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._started = time.time()  # the zombie Fast DDS segments `stop` removes are those created since
        if self.log_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="robotino_nodes_")
            self.log_dir = Path(self._tmp.name)
        self.log_dir = Path(self.log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)

    @property
    def logs(self) -> Path:
        """The folder of the nodes' logs: `log_dir`, or the temporary folder made for it."""
        assert self.log_dir is not None  # (set by __post_init__)
        return self.log_dir

    def start(self, executable: str, args: list[str], module: str | None = None) -> NodeProcess:
        """Start `executable` (a key of `NODE_MODULES`, or any name with the
        `module` to run) in its own process group.

        The nodes get one BLAS thread (``OPENBLAS_NUM_THREADS=1`` unless set): their matrices are 3x3 to
        9x9, where OpenBLAS's threads only add wake-ups (a 3x3 `expm` took 20 ms instead of 0.12 ms on a
        loaded 2-core machine).
        """
        out = self.logs / f"{executable}.out.log"
        err = self.logs / f"{executable}.err.log"
        env = {"OPENBLAS_NUM_THREADS": "1", **os.environ, "PYTHONUNBUFFERED": "1", "RCUTILS_COLORIZED_OUTPUT": "0",
               **self.env}
        env.update(dds_environment(env))
        with open(out, "wb") as fout, open(err, "wb") as ferr:
            popen = subprocess.Popen(
                [*self.prefix, sys.executable, "-m",
                 module or NODE_MODULES[executable], *args],
                stdout=fout,
                stderr=ferr,
                stdin=subprocess.DEVNULL,
                env=env,
                start_new_session=True,
            )
        node = NodeProcess(executable, popen, out, err)
        self.nodes.append(node)
        return node

    def check(self) -> None:
        """Raise `NodeFailed` if a node has exited with a non-zero status."""
        for node in self.nodes:
            code = node.popen.poll()
            if code not in (None, 0):
                raise NodeFailed(f"{node.name} exited with status {code}:\n{node.stderr_tail()}")

    def wait(self, node: NodeProcess, timeout_s: float | None = None, done: Callable[[], bool] | None = None,
             poll_s: float = 1.0) -> bool:
        """Wait until `node` exits or `done()` is true (True), or `timeout_s` passes (False); raise `NodeFailed`
        if any node fails. Woken at once by an exit; `done` is looked at every `poll_s`.
        """
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            self.check()
            if node.popen.poll() is not None or (done is not None and done()):
                return True
            left = poll_s if deadline is None else deadline - time.monotonic()
            if left <= 0.0:
                return False
            wait_for_exit([n.popen for n in self.nodes], min(left, poll_s))

    def stop(self, grace_s: float = 5.0) -> None:
        """SIGINT every running node, then SIGTERM, then SIGKILL, each after `grace_s`; reap all."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            running = [n for n in self.nodes if n.popen.poll() is None]
            if not running:
                break
            if sig == signal.SIGKILL:
                _print_stacks(running)
            for node in running:
                try:
                    os.killpg(node.popen.pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + grace_s
            while time.monotonic() < deadline and any(n.popen.poll() is None for n in running):
                wait_for_exit([n.popen for n in running], deadline - time.monotonic())
        for node in self.nodes:
            if node.popen.poll() is None:
                node.popen.wait()
        remove_zombie_segments(self._started)  # a node killed (here or by anyone) leaves its segment in RAM

    def stop_node(self, node: NodeProcess, grace_s: float = 5.0) -> int:
        """Stop one node the same way; returns its exit status."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if node.popen.poll() is not None:
                break
            if sig == signal.SIGKILL:
                _print_stacks([node])
            try:
                os.killpg(node.popen.pid, sig)
            except ProcessLookupError:
                pass
            wait_for_exit([node.popen], grace_s)
        return node.popen.wait()

    def __enter__(self) -> NodeGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
