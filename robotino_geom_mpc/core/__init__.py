"""The math core: plain numpy/scipy, never rclpy."""
