"""ROS 2 plumbing the nodes share: QoS, parameters from the specs, CDR fast paths, messages, the main loop, processes.

Every module here but `decode`, `processes` and `signals` imports rclpy; nothing outside
the nodes, the recorder and this subpackage does at import time.
"""
