"""Offline closed loop: simulation, Monte-Carlo study, run results, metrics and figures (no ROS)."""
