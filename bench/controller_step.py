"""One control step (MPCs + T(theta) + inverse drive) against OSQP on the same MPC problems.

Usage: python bench/controller_step.py [--quick]   (same as `robotino-geom-mpc bench --only controller_step`)
"""

import json
import sys

from robotino_geom_mpc.benchmarks import run_benchmarks

if __name__ == "__main__":
    print(json.dumps(run_benchmarks(quick="--quick" in sys.argv[1:], names=["controller_step"]), indent=2))
