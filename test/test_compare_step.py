"""`bench.compare_step`: this tree's controller against the tree before the folders by concept (commit e15c654).

The house's moves (84c93d4 on) were to leave behaviour unchanged: the controller of the tree before them, run in
its own process on the same paper-circle inputs, gives the same voltages to the last bit.
"""

import subprocess
from pathlib import Path

import pytest

from robotino_geom_mpc.bench.compare_step import compare_step
from robotino_geom_mpc.bench.registry import BenchmarkError

pytestmark = pytest.mark.ros

BEFORE_THE_FOLDERS = "e15c654"  # the last commit with core/ (84c93d4's parent)


def test_the_controller_before_the_folders_by_concept_gives_the_same_voltages(tmp_path):
    repo = Path(__file__).resolve().parents[1]
    archive = subprocess.run(["git", "-C", str(repo), "archive", BEFORE_THE_FOLDERS, "robotino_geom_mpc", "config"],
                             capture_output=True)
    if archive.returncode != 0:
        pytest.skip(f"this clone has no commit {BEFORE_THE_FOLDERS} (a shallow clone): {archive.stderr[-200:]!r}")
    subprocess.run(["tar", "-x", "-C", str(tmp_path)], input=archive.stdout, check=True)
    assert (tmp_path / "robotino_geom_mpc" / "core" / "controller.py").is_file()  # the old layout
    figures = compare_step(tmp_path, steps=300, repeats=1)
    assert figures["max_voltage_difference_v"] == 0.0


def test_a_folder_without_the_package_is_a_clear_error(tmp_path):
    with pytest.raises(BenchmarkError, match="no package robotino_geom_mpc"):
        compare_step(tmp_path, steps=10, repeats=1)
