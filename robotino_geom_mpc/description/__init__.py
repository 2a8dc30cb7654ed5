"""The robot description: the Robotino's URDF generated from its parameters, and URDF joints read back (no rclpy)."""
