"""robotino_geom_mpc: geometric decoupling plus decoupled MPC for the Festo Robotino.

The folders follow the paper and its Fig. 3: `params` (the specs), `model` (Section II: body, drives,
their integration), `geometric` (Sections III-IV: subspaces, T(theta), functional controllability),
`reference` (C^3 trajectories and the preview), `control` (Section V: MPCs, inverse drive), then the
offline loop (`offline`), the ROS 2 adapters (`ros`, `nodes`, `robotino_sim_node`), recording, `cli`.
"""

__version__ = "0.1.0"

from robotino_geom_mpc.system.signals import stop_signals_early as _stop_signals_early

_stop_signals_early()  # in a node process SIGINT/SIGTERM set a stop flag from here on (system/signals.py)
