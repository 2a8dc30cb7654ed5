"""Real-time factor of the offline closed loop on a 60 s paper-circle.

Usage: python bench/offline_sim.py [--quick]   (same as `robotino-geom-mpc bench --only offline_sim`)
"""

import json
import sys

from robotino_geom_mpc.benchmarks import run_benchmarks

if __name__ == "__main__":
    print(json.dumps(run_benchmarks(quick="--quick" in sys.argv[1:], names=["offline_sim"]), indent=2))
