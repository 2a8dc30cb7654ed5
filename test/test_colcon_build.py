"""`colcon build` of the package into a temporary directory: the ament layout, and an installed node on DDS."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from trajectory_msgs.msg import MultiDOFJointTrajectory

from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.ros.qos import LATCHED_QOS, PUBLISH_QOS
from harness import Harness
from robotino_geom_mpc.system.processes import ros_args
import launch_standins as standins
import ament_index_python.packages

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "robotino_geom_mpc"
EXECUTABLES = ("plant_node", "controller_node", "trajectory_node", "recorder_node")


def _share(install: Path):
    def share(package: str) -> str:
        assert package == PACKAGE, package
        return str(install / "share" / PACKAGE)
    return share


def _no_robot_state_publisher(package: str) -> str:
    raise ament_index_python.packages.PackageNotFoundError(package)


@pytest.fixture(scope="module")
def install(tmp_path_factory):
    base = tmp_path_factory.mktemp("colcon")
    colcon = Path(sys.executable).with_name("colcon")
    proc = subprocess.run(
        [str(colcon), "--log-base", str(base / "log"), "build", "--base-paths", str(REPO),
         "--build-base", str(base / "build"), "--install-base", str(base / "install"),
         "--packages-select", PACKAGE],
        capture_output=True, text=True, timeout=300, cwd=base,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return base / "install" / PACKAGE


def test_ament_layout(install):
    for name in EXECUTABLES:
        exe = install / "lib" / PACKAGE / name
        assert exe.is_file() and os.access(exe, os.X_OK), exe
    assert (install / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    share = install / "share" / PACKAGE
    assert (share / "package.xml").is_file()
    assert (share / "launch" / "robotino_geom_mpc.launch.py").is_file()
    assert sorted(p.name for p in (share / "config").iterdir()) == sorted(
        p.name for p in (REPO / "config").iterdir())  # the presets and the Fast DDS profile


def test_installed_executable_answers_on_dds(install):
    site = next((install / "lib").glob("python3*/site-packages"))
    env = {**os.environ, "PYTHONPATH": str(site),
           "AMENT_PREFIX_PATH": f"{install}{os.pathsep}{os.environ.get('AMENT_PREFIX_PATH', sys.prefix)}"}
    share_config = install / "share" / PACKAGE / "config" / "robotino2.yaml"
    with Harness("colcon_test") as h:
        paths = h.collect("/colcon_probe/reference_path", PathMsg, LATCHED_QOS)
        previews = h.collect("/colcon_probe/reference_preview", MultiDOFJointTrajectory)  # as a controller would
        h.node.create_publisher(Odometry, "/colcon_probe/odom", PUBLISH_QOS)  # as a robot would: the reference starts
        proc = subprocess.Popen(
            [str(install / "lib" / PACKAGE / "trajectory_node"),
             *ros_args(share_config, {"scenario": "lemniscate"}), "-r", "__ns:=/colcon_probe"],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
        )
        try:
            assert h.spin_until(lambda: len(paths) == 1 and len(previews) >= 3, 30.0)
            assert len(previews[0].points) == load_params(share_config)[1].horizon + 1
        finally:
            os.killpg(proc.pid, signal.SIGTERM)  # a clean stop on SIGTERM too
            out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and b"Traceback" not in err


# each launch file with the arguments that change which executables it starts
LAUNCHES = [("robotino_geom_mpc.launch.py", {}), ("robotino_geom_mpc.launch.py", {"record": "true", "robots": "3"}),
            ("real_robot.launch.py", {"record": "true"}), ("robot_side.launch.py", {}),
            ("driver_standin.launch.py", {})]


def test_every_launch_file_starts_only_installed_executables_and_files(install, monkeypatch):
    """Each launch file, evaluated with the stand-ins as launch would (`launch_standins`), its package's share the
    colcon install: every executable of ours it starts is installed in lib/, every file it passes exists.
    """
    standins.install(monkeypatch.setitem)
    monkeypatch.setattr(ament_index_python.packages, "get_package_share_directory", _no_robot_state_publisher)
    started: set[str] = set()
    for name, arguments in LAUNCHES:
        launch = install / "share" / PACKAGE / "launch" / name
        actions, _ = standins.evaluate(standins.load_description(launch), arguments, _share(install))
        for node in standins.of("Node", actions):
            if node.kwargs["package"] == PACKAGE:
                started.add(node.kwargs["executable"])
                assert (install / "lib" / PACKAGE / node.kwargs["executable"]).is_file(), (name, node.kwargs)
            for entry in node.kwargs.get("parameters", []):
                assert not isinstance(entry, str) or not entry or Path(entry).is_file(), (name, entry)
    assert set(EXECUTABLES) <= started, started
    text = (install / "share" / PACKAGE / "launch" / "robotino_geom_mpc.launch.py").read_text()
    assert '"robotino3.yaml"' in text and (install / "share" / PACKAGE / "config" / "robotino3.yaml").is_file()
