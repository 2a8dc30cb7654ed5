"""C^3 references: time laws, trajectories, goal motions, timed paths, and the N-step preview."""
