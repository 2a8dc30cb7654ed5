"""`MotionController.step` of this tree against another source tree's, interleaved pass by pass.

``python -m robotino_geom_mpc.bench.compare_step SOURCE_ROOT`` (e.g. a checkout
of an earlier commit) prints the median time per step of both controllers on
the inputs of the ``controller_step`` benchmark, their ratio and the largest
difference of their voltages. The other tree's controller runs in a process of
its own (its package imports itself by name, so two trees cannot share one
process), started with the other tree first on the path; the two processes'
passes alternate, so both see the same machine load.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from robotino_geom_mpc.bench.controller_step import step_inputs
from robotino_geom_mpc.bench.registry import BenchmarkError, median_per_call
from robotino_geom_mpc.control.motion_controller import MotionController

__all__ = ["compare_step", "main"]

# the other tree's side: its own controller on the inputs in argv[1], the voltages to argv[2], then one pass per
# line read ("done" after each); either layout (the folders by concept, or core/ before 84c93d4)
_OTHER = """
import sys
from pathlib import Path
import numpy as np
try:
    from robotino_geom_mpc.control.motion_controller import MotionController
    from robotino_geom_mpc.params.files import load_params
except ImportError:
    from robotino_geom_mpc.core.controller import MotionController
    from robotino_geom_mpc.core.params import load_params
import robotino_geom_mpc as package
assert Path(package.__file__).resolve().is_relative_to(Path(sys.argv[3]).resolve()), package.__file__
inputs = np.load(sys.argv[1])
X, previews = inputs["X"], inputs["previews"]
controller = MotionController(*load_params())
def run():
    controller.reset()
    return [controller.step(X[k], previews[k]).voltages for k in range(len(X))]
np.save(sys.argv[2], np.array(run()))
print("ready", flush=True)
for _ in sys.stdin:
    run()
    print("done", flush=True)
"""


def _other_process(source_root: Path, inputs: Path, voltages: Path) -> subprocess.Popen:
    """The other tree's controller process (`_OTHER`), its package first on the path."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(source_root), os.environ.get("PYTHONPATH"))))}
    return subprocess.Popen([sys.executable, "-c", _OTHER, str(inputs), str(voltages), str(source_root)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=source_root)


def compare_step(source_root: str | Path, steps: int = 1000, repeats: int = 15) -> dict[str, float]:
    """Time `MotionController.step` of this tree and of `source_root`'s on the same inputs, interleaved.

    Both controllers step through the paper-circle states and previews of
    `step_inputs` from a reset; their passes alternate `repeats` times. The
    other's pass is timed here, around a line sent and one read (some 50 us a
    pass, 0.05 us a step).

    Returns
    -------
    dict
        ``controller_step_us`` and ``other_controller_step_us`` (medians per
        step), ``ratio_this_over_other`` and ``max_voltage_difference_v``
        (0 up to rounding for the same control law).

    Raises
    ------
    BenchmarkError
        If `source_root` holds no package ``robotino_geom_mpc``, or its controller fails.
    """
    root = Path(source_root).resolve()
    if not (root / "robotino_geom_mpc" / "__init__.py").is_file():
        raise BenchmarkError(f"{source_root}: no package robotino_geom_mpc")
    X, previews, robot, control = step_inputs(steps)
    this = MotionController(robot, control)
    with tempfile.TemporaryDirectory() as folder:
        inputs, theirs = Path(folder) / "inputs.npz", Path(folder) / "voltages.npy"
        np.savez(inputs, X=X, previews=previews)
        other = _other_process(root, inputs, theirs)
        try:
            stdin, stdout = other.stdin, other.stdout
            assert stdin is not None and stdout is not None  # (both pipes)
            if stdout.readline().strip() != "ready":
                raise BenchmarkError(f"{source_root}: its controller failed (exit {other.wait()})")
            this.reset()
            ours = np.array([this.step(X[k], previews[k]).voltages for k in range(steps)])
            diff = float(np.abs(ours - np.load(theirs)).max())

            def run_this() -> None:
                this.reset()
                for k in range(steps):
                    this.step(X[k], previews[k])

            def run_other() -> None:
                stdin.write("pass\n")
                stdin.flush()
                if stdout.readline().strip() != "done":
                    raise BenchmarkError(f"{source_root}: its controller stopped mid-pass")

            this_s, other_s = median_per_call([run_this, run_other], steps, repeats)
        finally:
            other.kill()
            other.wait()
    return {
        "controller_step_us": this_s * 1e6,
        "other_controller_step_us": other_s * 1e6,
        "ratio_this_over_other": this_s / other_s,
        "max_voltage_difference_v": diff,
    }


def main(argv: list[str] | None = None) -> None:
    """Command line: print the figures of `compare_step`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source_root", help="root of the other source tree (holds robotino_geom_mpc/)")
    parser.add_argument("--steps", type=int, default=1000, help="control steps per pass (default 1000)")
    parser.add_argument("--repeats", type=int, default=15, help="interleaved passes of each (default 15)")
    args = parser.parse_args(argv)
    for key, value in compare_step(args.source_root, args.steps, args.repeats).items():
        print(f"{key}: {value:.6g}")


if __name__ == "__main__":
    main()
