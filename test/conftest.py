"""Test session setup: an isolated DDS domain and the ament index of the venv.

Set before anything imports rclpy: each session gets its own random
ROS_DOMAIN_ID and discovery stays on localhost.
"""

import os
import random
import sys

os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
