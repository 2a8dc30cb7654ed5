"""The control loop's two sides as plain objects (no rclpy): what the nodes, the offline runs and the replay drive."""
