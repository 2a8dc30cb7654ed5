"""Section V and around it: the decoupled MPCs, the motion controller, inverse drive, estimator, limits."""
