"""The Robotino plant simulator: integration core and its ROS 2 node."""
