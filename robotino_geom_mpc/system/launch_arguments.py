"""What the package's launch files share: their arguments' checks, the nodes' environment, the real driver's names.

Plain Python (no `launch` import), so the launch files and the tests that read them use one definition.

The robocup-logistics driver (https://github.com/robocup-logistics/ros2-robotino at commit
dc2883a2dbc6231b5364f3ab0800133ab8b762f3; docs/howto/real_robotino.md): its launch file
``rto_node/launch/robotino_driver.launch.py`` starts the executable ``rto_node`` as the node
``robotino_node`` (subscribes ``cmd_vel``, geometry_msgs/Twist) and ``rto_odometry_node`` as
``robotino_odometry_node`` (publishes ``odom``, nav_msgs/Odometry), both in the launch argument
``namespace`` (default ``""``: the topics are ``/cmd_vel`` and ``/odom``). Both endpoints are created
with a depth of 10 and rclcpp's default QoS otherwise: reliable, volatile, keep-last.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

__all__ = ["DRIVER_NODE", "DRIVER_ODOMETRY_NODE", "DRIVER_TOPICS", "DRIVER_QOS_DEPTH", "NAV2_BEHAVIOR_TREE",
           "NAV2_SERVERS", "STANDIN_HIDDEN", "driver_remaps", "flag", "node_environment", "number"]

DRIVER_NODE = "robotino_node"  # rto_node: cmd_vel in
DRIVER_ODOMETRY_NODE = "robotino_odometry_node"  # rto_odometry_node: odom out
DRIVER_TOPICS = ("odom", "cmd_vel")  # relative: in the driver's namespace
DRIVER_QOS_DEPTH = 10  # both endpoints: reliable, volatile, keep-last 10
# the stand-in driver's topics that no real driver publishes, moved under a hidden name (a leading underscore:
# `ros2 topic list` and the recorder skip it), so no recording or report takes the emulation's truth for the robot's
STANDIN_HIDDEN = ("ground_truth/odom", "wheel_currents", "applied_voltages")
# Nav2 (jazzy) beside a real robot, the trajectory node in controller_server's place (docs/howto/nav2.md): the servers
# nav2_bringup's navigation_launch.py starts that a navigate_to_pose with replanning needs (package, executable),
# managed by a lifecycle_manager; bt_navigator runs nav2_bt_navigator's tree that replans at 1 Hz with no recovery
# behaviours (behavior_server's spin and back-up publish cmd_vel themselves, against this controller's)
NAV2_SERVERS = (("nav2_planner", "planner_server"), ("nav2_bt_navigator", "bt_navigator"),
                ("nav2_waypoint_follower", "waypoint_follower"))
NAV2_BEHAVIOR_TREE = ("nav2_bt_navigator", "behavior_trees", "navigate_w_replanning_time.xml")


def flag(config: Mapping[str, str], name: str) -> bool:
    """A true/false launch argument (as launch's conditions read it: true, false, 1, 0)."""
    value = config[name].strip().lower()
    if value not in ("true", "false", "1", "0"):
        raise ValueError(f"launch argument '{name}' must be true or false, got {config[name]!r}")
    return value in ("true", "1")


def number(config: Mapping[str, str], name: str, kind: type = float) -> float:
    """A non-negative finite number from a launch argument."""
    try:
        value = kind(config[name])
    except ValueError:
        raise ValueError(f"launch argument '{name}' must be a number, got {config[name]!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"launch argument '{name}' must be finite and >= 0, got {config[name]!r}")
    return value


def node_environment(config: Mapping[str, str]) -> dict[str, str]:
    """The nodes' additional environment: one BLAS thread, and the launch argument ``fastdds_profile`` if not empty."""
    env = {"OPENBLAS_NUM_THREADS": "1"}
    if config["fastdds_profile"]:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = config["fastdds_profile"]
    return env


def driver_remaps(namespace: str) -> list[tuple[str, str]]:
    """Remappings pinning ``odom`` and ``cmd_vel`` to the driver's topics in `namespace` (`ros_namespace` form)."""
    return [(topic, f"{namespace}/{topic}") for topic in DRIVER_TOPICS]
