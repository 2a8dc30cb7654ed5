"""robotino_geom_mpc: geometric decoupling plus decoupled MPC for the Festo Robotino.

Folders follow the data flow of the paper's Fig. 3: `core` (the math:
parameters, model, geometric toolbox, decoupling, trajectory, MPC, inverse
drive), `robotino_sim_node` (the plant), `nodes` (ROS 2 adapters),
`recording` (MCAP), `cli` (the `robotino-geom-mpc` command).
"""

__version__ = "0.1.0"

from robotino_geom_mpc.ros.signals import stop_signals_early as _stop_signals_early

_stop_signals_early()  # in a node process SIGINT/SIGTERM set a stop flag from here on (ros/signals.py)
