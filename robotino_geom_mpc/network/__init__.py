"""Networked control: the link model between two hosts (no rclpy)."""
