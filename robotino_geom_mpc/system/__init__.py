"""Process plumbing that is not ROS: start and stop node processes, signals, shared-memory clean-up."""
