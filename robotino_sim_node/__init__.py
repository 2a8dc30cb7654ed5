"""The Robotino plant simulator node: the plant of `robotino_geom_mpc.model` on DDS."""

from robotino_geom_mpc.system.signals import stop_signals_early as _stop_signals_early

_stop_signals_early()  # in a node process SIGINT/SIGTERM set a stop flag from here on (system/signals.py)
