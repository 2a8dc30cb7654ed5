"""The repository is self-contained: no tracked file cites a path outside it (a clone has none of those files).

The facts the code and the presets rely on live in docs/ (docs/theory.md, docs/robotino.md); a citation of a
notes folder beside the checkout or of the machine it was written on would point a reader at nothing.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros  # lists the tracked files with git (a child process)

ROOT = Path(__file__).resolve().parents[1]
# a notes folder beside the checkout, or an absolute path of the machine it was written on (not a URL's path)
OUTSIDE = re.compile(rb"\.\./" + rb"shared\b|(?<![\w.\-/])/" + rb"work/")
# without git (an unpacked source tree): every file but these folders (build outputs, caches, environments)
UNTRACKED_DIRS = {".git", ".venv", "build", "install", "log", "out", "_build", "_generated", "__pycache__",
                  ".pytest_cache", ".mypy_cache", ".ruff_cache", ".hypothesis", ".import_linter_cache"}


def _files() -> list[Path]:
    git = shutil.which("git")
    if git is not None and (ROOT / ".git").exists():
        listed = subprocess.run([git, "-C", str(ROOT), "ls-files", "-z"], capture_output=True, check=True).stdout
        return [ROOT / name for name in listed.decode().split("\0") if name]
    return [p for p in ROOT.rglob("*") if p.is_file() and not UNTRACKED_DIRS & set(p.relative_to(ROOT).parts)
            and not p.name.endswith(".egg-info")]


def citations_outside(text: bytes) -> list[tuple[int, str]]:
    """(line number, line) of every citation of a path outside the repository in `text`."""
    return [(n, line.decode(errors="replace").strip()) for n, line in enumerate(text.splitlines(), 1)
            if OUTSIDE.search(line)]


def test_the_detector_finds_paths_outside_and_leaves_urls_alone():
    planted = b"".join((b"# Sources: ../", b"shared", b"/NOTES.md\n", b"x = '/", b"work/main/config'\n",
                        b"see https://example.org/", b"work/page and docs/robotino.md\n"))
    assert [n for n, _ in citations_outside(planted)] == [1, 2]


def test_no_tracked_file_cites_a_path_outside_the_repository():
    files = _files()
    assert any(p.name == "robotino3.yaml" for p in files)  # the listing reaches the presets
    found = [f"{p.relative_to(ROOT)}:{n}: {line}" for p in files if p.exists()
             for n, line in citations_outside(p.read_bytes())]
    assert not found, "paths outside the repository (cite docs/ instead):\n" + "\n".join(found)
