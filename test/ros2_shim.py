"""A test-only ``ros2`` command: just what docs/howto/real_robotino.md's commands use (no ``ros2`` CLI on PyPI).

test_real_robot_page puts a ``ros2`` script running this module first on PATH, then runs the page's blocks.

``ros2 launch PKG FILE [name:=value ...]``
    Evaluates the launch file with the launch stand-ins (test/launch_standins.py) and starts each node it names
    as ``<venv>/bin/<executable> --ros-args -r __node:=NAME -r __ns:=NS -r FROM:=TO ... --params-file ...`` (a
    dict of parameters written as launch_ros writes it), with the node's additional environment, as launch_ros
    does; ``rto_node``'s launch is the stand-in driver (launch/driver_standin.launch.py). On SIGINT (Ctrl-C) or
    SIGTERM it sends SIGINT to every node and waits for them; it exits when they have all exited.
``ros2 service call SERVICE std_srvs/srv/SetBool '{data: BOOL}'``
    One call through an rclpy client (waits up to 20 s for the service).
``ros2 run PKG EXECUTABLE ARGS``
    ``<venv>/bin/EXECUTABLE ARGS``.
``ros2 pkg prefix robotino_geom_mpc``
    ``$ROS2_SHIM_PREFIX`` (whose share/robotino_geom_mpc is the source tree).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_standins import LAUNCH_DIR, REPO, evaluate, install, launch_ros_file, load_description, of  # noqa: E402

BIN = Path(sys.executable).parent
PACKAGE = "robotino_geom_mpc"
LAUNCH_FILES = {("rto_node", "robotino_driver.launch.py"): LAUNCH_DIR / "driver_standin.launch.py"}


def _share(package: str) -> str:
    if package != PACKAGE:
        raise SystemExit(f"ros2 (test shim): package {package!r} not found")
    return str(REPO)


def _node_argv(node, folder: Path) -> list[str]:
    """The command line launch_ros gives a Node action."""
    kwargs = node.kwargs
    argv = [str(BIN / kwargs["executable"]), *kwargs.get("arguments", []), "--ros-args"]
    if kwargs.get("name"):
        argv += ["-r", f"__node:={kwargs['name']}"]
    if kwargs.get("namespace"):
        argv += ["-r", f"__ns:={kwargs['namespace']}"]
    for source, target in kwargs.get("remappings", []):
        argv += ["-r", f"{source}:={target}"]
    for i, entry in enumerate(kwargs.get("parameters", [])):
        if isinstance(entry, dict):
            path = folder / f"{kwargs['executable']}_{i}.yaml"
            path.write_text(launch_ros_file(node, entry))
            entry = path
        argv += ["--params-file", str(entry)]
    return argv


def launch(package: str, filename: str, arguments: list[str]) -> int:
    path = LAUNCH_FILES.get((package, filename)) or (Path(_share(package)) / "launch" / filename)
    if not path.is_file():
        raise SystemExit(f"ros2 (test shim): no launch file {filename!r} in package {package!r}")
    values = dict(a.split(":=", 1) for a in arguments)
    install()
    actions, _ = evaluate(load_description(path), values, _share)
    folder = Path(tempfile.mkdtemp(prefix="ros2_shim_"))
    nodes = []
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    for node in of("Node", actions):
        env = {**os.environ, **node.kwargs.get("additional_env", {})}
        nodes.append(subprocess.Popen(_node_argv(node, folder), env=env, start_new_session=True))
    while not stop and any(p.poll() is None for p in nodes):
        time.sleep(0.05)
    for p in nodes:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    deadline = time.monotonic() + 20.0
    for p in nodes:
        try:
            p.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    return 0


def service_call(service: str, kind: str, values: str) -> int:
    if kind != "std_srvs/srv/SetBool":
        raise SystemExit(f"ros2 (test shim): service type {kind!r} not supported")
    import rclpy
    from std_srvs.srv import SetBool

    request = SetBool.Request(data=bool(yaml.safe_load(values)["data"]))
    rclpy.init()
    node = rclpy.create_node("ros2_shim_service_call")
    try:
        client = node.create_client(SetBool, service)
        if not client.wait_for_service(timeout_sec=20.0):
            print(f"waiting for service {service} to become available... timed out", file=sys.stderr)
            return 1
        print(f"requester: making request: {request}")
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=20.0)
        if future.result() is None:
            return 1
        print(f"response:\n{future.result()}")
        return 0
    finally:
        node.destroy_node()
        rclpy.shutdown()


def main(argv: list[str]) -> int:
    if argv[:1] == ["launch"] and len(argv) >= 3:
        return launch(argv[1], argv[2], argv[3:])
    if argv[:2] == ["service", "call"] and len(argv) == 5:
        return service_call(*argv[2:])
    if argv[:1] == ["run"] and len(argv) >= 3 and argv[1] == PACKAGE:
        os.execv(BIN / argv[2], [str(BIN / argv[2]), *argv[3:]])
    if argv[:2] == ["pkg", "prefix"] and argv[2:] == [PACKAGE]:
        print(os.environ["ROS2_SHIM_PREFIX"])
        return 0
    print(f"ros2 (test shim): not supported: {' '.join(argv)}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
