"""docs/howto/real_robotino.md's bring-up, run verbatim against the stand-in driver.

The page marks its command blocks (``<!-- page-test: NAME -->`` before a fenced block); this test extracts them
in order, compares them with its own copy (`EXPECTED`: a changed command fails here until the test follows it),
and runs each one with bash as a person would, in one working folder: the background ones (the driver, the
controller's launch) in their own process group, stopped with SIGINT (Ctrl-C) at the end. ``ros2`` is a
test-only command first on PATH (test/ros2_shim.py): ``ros2 launch rto_node robotino_driver.launch.py`` starts
launch/driver_standin.launch.py (the emulated driver + firmware chain under the driver's names), the package's
launches are evaluated with the launch stand-ins and their nodes started as launch_ros would.

Checked against the stand-in's hidden ground truth (``/_standin/ground_truth/odom``: the emulation's true pose,
which no node of the page reads): while disabled the controller sends zero twists and the reference holds its
start at the robot, where identify left it; the reference starts (its path's first pose) at the robot's pose at
the enable, and from the enable to the disable the robot follows paper-circle (the reference's point 0 of each
preview) within 3 mm RMS and 6 mm at most (the chain's measured 0.93 mm offline and 0.94 mm over DDS, 1.1 mm
at most from an enable in test_controller_loop_cases, with room for a loaded 2-core host): no catch-up; after the
disable every twist is zero and the robot comes to rest. The page's last block reports the recording (which
holds no ground truth) from odometry and says so, and regress reproduces every twist of it.
"""

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry, Path as PathMsg
from trajectory_msgs.msg import MultiDOFJointTrajectory

from harness import Harness
from robotino_geom_mpc.ros.messages import quaternion_to_yaw
from robotino_geom_mpc.ros.qos import LATCHED_QOS

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "howto" / "real_robotino.md"
SHIM = Path(__file__).resolve().parent / "ros2_shim.py"
BACKGROUND = ("driver", "launch")  # blocks that keep running in their terminal
EXPECTED = [  # the page's marked blocks, in order
    ("driver", "ros2 launch rto_node robotino_driver.launch.py hostname:=172.26.1.1:12080 launch_joynode:=false "
               "launch_teleopnode:=false"),
    ("params", 'cp "$(ros2 pkg prefix robotino_geom_mpc)/share/robotino_geom_mpc/config/robotino3_real.yaml" '
               "my_robotino3.yaml"),
    ("preflight", "robotino-geom-mpc preflight --params my_robotino3.yaml"),
    ("identify", "robotino-geom-mpc identify --ros --out my_chain"),
    ("launch", "ros2 launch robotino_geom_mpc real_robot.launch.py params_file:=my_robotino3.yaml "
               "chain_params:=my_chain/chain_params.yaml record:=true bag:=circle_bag"),
    ("enable", "ros2 service call /robotino_controller/enable std_srvs/srv/SetBool '{data: true}'"),
    ("disable", "ros2 service call /robotino_controller/enable std_srvs/srv/SetBool '{data: false}'"),
    ("report", "robotino-geom-mpc report circle_bag --out circle_report\n"
               "robotino-geom-mpc regress circle_bag"),
]
TRACK_S = 14.0  # of paper-circle between the enable and the disable (the reference lasts 22 s)
RMS_BOUND_M, MAX_BOUND_M = 3e-3, 6e-3  # from the enable to the disable
_BLOCK = re.compile(r"^[ \t]*<!-- page-test: ([\w-]+) -->[ \t]*\n([ \t]*)```bash\n(.*?)\n[ \t]*```", re.M | re.S)


def page_blocks(text: str) -> list[tuple[str, str]]:
    """The marked blocks of the page, (name, command text without the list item's indentation), in order."""
    return [(name, "\n".join(line.removeprefix(indent) for line in body.splitlines()))
            for name, indent, body in _BLOCK.findall(text)]


@pytest.mark.unit
def test_the_pages_commands_are_the_ones_this_test_runs():
    assert page_blocks(PAGE.read_text()) == EXPECTED


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


@pytest.fixture
def terminal(tmp_path):
    """``terminal(name, text, background, spin)``: runs a block with bash in the working folder, as a person would."""
    work, bin_dir, prefix = tmp_path / "work", tmp_path / "bin", tmp_path / "prefix"
    for folder in (work, bin_dir, prefix / "share"):
        folder.mkdir(parents=True)
    (prefix / "share" / "robotino_geom_mpc").symlink_to(REPO)
    ros2 = bin_dir / "ros2"
    ros2.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{SHIM}" "$@"\n')
    ros2.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
           "ROS2_SHIM_PREFIX": str(prefix), "PYTHONUNBUFFERED": "1"}
    started: list[subprocess.Popen] = []

    def run(name: str, text: str, background: bool, spin) -> subprocess.Popen:
        log = (tmp_path / f"{name}.log").open("w")
        proc = subprocess.Popen(["bash", "-c", text], cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        if background:
            started.append(proc)
            return proc
        deadline = time.monotonic() + 120.0
        while proc.poll() is None and time.monotonic() < deadline:
            spin(0.05)  # the harness keeps receiving meanwhile
        rc = proc.wait(timeout=1.0)
        assert rc == 0, f"block {name!r} exited {rc}:\n{(tmp_path / f'{name}.log').read_text()[-3000:]}"
        return proc

    run.work = work
    run.log = lambda name: (tmp_path / f"{name}.log").read_text()
    yield run
    for proc in reversed(started):  # anything left: Ctrl-C, then kill
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


@pytest.mark.ros
@pytest.mark.slow
def test_the_bring_up_drives_the_standin_around_the_circle_and_stops(terminal):
    blocks = dict(page_blocks(PAGE.read_text()))
    assert list(blocks) == [name for name, _ in EXPECTED]
    with Harness("page_test") as h:
        truth = h.collect("/_standin/ground_truth/odom", Odometry)
        previews = h.collect("/reference_preview", MultiDOFJointTrajectory)
        paths = h.collect("/reference_path", PathMsg, LATCHED_QOS)
        twists: list[tuple[float, Twist]] = []
        h.node.create_subscription(Twist, "/cmd_vel", lambda m: twists.append((time.time(), m)), 100)

        driver = terminal("driver", blocks["driver"], background=True, spin=h.spin_for)
        assert h.spin_until(lambda: h.node.count_publishers("/odom") == 1, 30.0), terminal.log("driver")
        terminal("params", blocks["params"], background=False, spin=h.spin_for)
        terminal("preflight", blocks["preflight"], background=False, spin=h.spin_for)
        preflight = terminal.log("preflight")
        assert "PASS" in preflight and "FAIL" not in preflight, preflight
        terminal("identify", blocks["identify"], background=False, spin=h.spin_for)
        assert (terminal.work / "my_chain" / "chain_params.yaml").is_file()

        identified = len(twists)  # identify's commands
        launch = terminal("launch", blocks["launch"], background=True, spin=h.spin_for)
        # started disabled: the controller answers the odometry with zero twists, the reference holds its start
        assert h.spin_until(lambda: len(twists) >= identified + 30 and len(previews) >= 30, 60.0), \
            terminal.log("launch")
        held = [m for _, m in twists[identified:]]
        assert all(m.linear.x == m.linear.y == m.angular.z == 0.0 for m in held)
        stands = truth[-1].pose.pose
        enabled_at = time.time()
        holds = list(previews)
        terminal("enable", blocks["enable"], background=False, spin=h.spin_for)
        h.spin_for(TRACK_S)
        disabling_at = time.time()  # (the block takes a while: the controller is disabled somewhere in it)
        terminal("disable", blocks["disable"], background=False, spin=h.spin_for)
        disabled_at = time.time()
        h.spin_for(2.0)
        last_truth = truth[-1]

        os.killpg(launch.pid, signal.SIGINT)  # Ctrl-C in the launch's terminal, then the driver's
        assert launch.wait(30) == 0, terminal.log("launch")
        os.killpg(driver.pid, signal.SIGINT)
        assert driver.wait(30) == 0, terminal.log("driver")

    # held: every preview before the enable is the robot's pose where identify left it, at rest; the reference
    # starts there (t = 0: its path's first pose)
    pose = np.array([stands.position.x, stands.position.y, quaternion_to_yaw(stands.orientation)])
    for msg in holds:
        for point in msg.points:
            tf = point.transforms[0]
            assert np.abs([tf.translation.x - pose[0], tf.translation.y - pose[1],
                           math.remainder(quaternion_to_yaw(tf.rotation) - pose[2], math.tau)]).max() < 1e-6
            v, a = point.velocities[0], point.accelerations[0]
            assert v.linear.x == v.linear.y == v.angular.z == a.linear.x == a.linear.y == a.angular.z == 0.0
    start = paths[0].poses[0].pose
    assert math.hypot(start.position.x - pose[0], start.position.y - pose[1]) < 1e-6
    assert math.hypot(pose[0], pose[1]) > 0.2  # identify left it off the driver's origin
    started = _stamp(paths[0])
    assert started >= enabled_at
    # tracking: the truth against the reference from the start at the enable to the disable
    ref_t = np.array([_stamp(p) for p in previews])
    ref_xy = np.array([[p.points[0].transforms[0].translation.x, p.points[0].transforms[0].translation.y]
                       for p in previews])
    order = np.argsort(ref_t)
    ref_t, ref_xy = ref_t[order], ref_xy[order]
    samples = [(_stamp(m), m.pose.pose.position.x, m.pose.pose.position.y) for m in truth]
    window = np.array([s for s in samples if started <= s[0] <= disabling_at and ref_t[0] <= s[0] <= ref_t[-1]])
    reference = np.column_stack([np.interp(window[:, 0], ref_t, ref_xy[:, i]) for i in (0, 1)])
    errors = np.hypot(*(window[:, 1:] - reference).T)
    rms = math.sqrt(float(np.mean(errors ** 2)))
    span = np.ptp(window[:, 1:], axis=0)
    print(f"paper-circle through the stand-in, started at the enable from ({pose[0]:.3f} m, {pose[1]:.3f} m, "
          f"{pose[2]:.3f} rad), t = 0 {(started - enabled_at) * 1e3:.0f} ms after the enable command began: "
          f"{len(window)} samples over {window[-1, 0] - window[0, 0]:.1f} s: RMS {rms * 1e3:.3f} mm, "
          f"max {errors.max() * 1e3:.3f} mm; the path spans {span[0]:.2f} m x {span[1]:.2f} m")
    assert len(window) > 20 * TRACK_S  # the truth at each of the driver loop's 30 Hz passes, over the window
    assert rms <= RMS_BOUND_M and errors.max() <= MAX_BOUND_M
    assert span.min() > 0.5  # it went around the circle (1 m across), not stood on it
    # stopped: zero twists from the disable on (one in flight allowed), the truth at rest
    after = [m for at, m in twists if at > disabled_at + 0.1]
    assert after and all(m.linear.x == m.linear.y == m.angular.z == 0.0 for m in after)
    assert math.hypot(last_truth.twist.twist.linear.x, last_truth.twist.twist.linear.y) < 1e-3
    assert abs(last_truth.twist.twist.angular.z) < 1e-2
    assert (terminal.work / "circle_bag").is_dir()  # the recorder closed its bag on Ctrl-C
    # the figures of the real-like recording (no ground truth recorded: the stand-in hides it): from odometry,
    # said so; the replay reproduces every twist the controller sent
    terminal("report", blocks["report"], background=False, spin=lambda s: time.sleep(s))
    said = terminal.log("report")
    metrics = json.loads((terminal.work / "circle_report" / "metrics.json").read_text())
    assert "truth: odometry" in said and metrics["truth"] == "odometry", said
    assert all((terminal.work / "circle_report" / name).is_file() for name in ("xy_path.png", "theta.png",
                                                                                 "commands.png"))
    # odometry's error holds the dispatch delay on top of the true error (a few mm on the circle, not metres)
    assert 0.0 < metrics["rms_position_error_m"] < 0.02, metrics
    verdict = re.search(r"PASS: (\d+) of (\d+) ticks compared", said)
    assert verdict and int(verdict.group(1)) > 100, said
    # the chain identify fitted, from the bag: the controller's parameter events if the recorder caught them, else
    # the run parameters it stored (the launch gave it the controller's chain file); never the preset
    assert re.search(r"its parameters from the (controller's parameters in the recording|run parameters the "
                     r"recorder stored)", said), said
