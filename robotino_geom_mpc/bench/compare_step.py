"""`MotionController.step` of this tree against another source tree's, interleaved in one process.

``python -m robotino_geom_mpc.bench.compare_step SOURCE_ROOT`` (e.g. a checkout
of an earlier commit) prints the median time per step of both controllers on
the inputs of the ``controller_step`` benchmark, their ratio and the largest
difference of their voltages. Nothing is imported from another tree unless asked.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from robotino_geom_mpc.bench.controller_step import step_inputs
from robotino_geom_mpc.bench.registry import BenchmarkError, median_per_call
from robotino_geom_mpc.control.motion_controller import MotionController

__all__ = ["compare_step", "load_controller_class", "main"]

_OTHER_PACKAGE = "_compared_robotino_geom_mpc"


def load_controller_class(source_root: str | Path) -> type:
    """`MotionController` of the package ``robotino_geom_mpc`` under `source_root`, imported under another name.

    The other tree's package is loaded as ``_compared_robotino_geom_mpc`` (its
    relative imports resolve inside it), so both versions live in one process.

    Raises
    ------
    BenchmarkError
        If `source_root` holds no ``robotino_geom_mpc/control/motion_controller.py``.
    """
    package_dir = Path(source_root) / "robotino_geom_mpc"
    if not (package_dir / "core" / "controller.py").is_file():
        raise BenchmarkError(f"{source_root}: no robotino_geom_mpc/control/motion_controller.py")
    if _OTHER_PACKAGE not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            _OTHER_PACKAGE, package_dir / "__init__.py", submodule_search_locations=[str(package_dir)]
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[_OTHER_PACKAGE] = module
        spec.loader.exec_module(module)
    return importlib.import_module(f"{_OTHER_PACKAGE}.core.controller").MotionController


def compare_step(source_root: str | Path, steps: int = 1000, repeats: int = 15) -> dict[str, float]:
    """Time `MotionController.step` of this tree and of `source_root`'s on the same inputs, interleaved.

    Both controllers step through the paper-circle states and previews of
    `step_inputs` from a reset; their passes alternate `repeats` times so that
    both see the same machine load.

    Returns
    -------
    dict
        ``controller_step_us`` and ``other_controller_step_us`` (medians per
        step), ``ratio_this_over_other`` and ``max_voltage_difference_v``
        (0 up to rounding for the same control law).
    """
    X, previews, robot, control = step_inputs(steps)
    this, other = MotionController(robot, control), load_controller_class(source_root)(robot, control)

    def voltages(controller: object) -> np.ndarray:
        controller.reset()
        return np.array([controller.step(X[k], previews[k]).voltages for k in range(steps)])

    diff = float(np.abs(voltages(this) - voltages(other)).max())

    def timed(controller: object) -> Callable[[], None]:
        def run() -> None:
            controller.reset()
            for k in range(steps):
                controller.step(X[k], previews[k])

        return run

    this_s, other_s = median_per_call([timed(this), timed(other)], steps, repeats)
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
