"""The Robotino plant simulator: integration core and its ROS 2 node."""

from robotino_geom_mpc.ros.signals import stop_signals_early as _stop_signals_early

_stop_signals_early()  # in a node process SIGINT/SIGTERM set a stop flag from here on (ros/signals.py)
