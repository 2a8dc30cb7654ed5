"""Section III-IV: Basile-Marro subspace algebra, the decoupling field T(theta), functional controllability."""
