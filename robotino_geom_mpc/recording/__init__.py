"""MCAP recording (rosbag2 conventions), replay and reports."""
