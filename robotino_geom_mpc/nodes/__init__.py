"""ROS 2 nodes: thin adapters over the math core."""
