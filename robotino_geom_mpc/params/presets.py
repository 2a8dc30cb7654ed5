"""Where the shipped presets and config files are: the installed share directory (ament index), else the source tree."""

from __future__ import annotations

from pathlib import Path

from robotino_geom_mpc.params.specs import ParamError

__all__ = ["config_file", "default_params_file", "preset_file"]


def preset_file(name: str) -> Path:
    """Path of a shipped preset (`robotino3`, `robotino2`)."""
    return config_file(f"{name}.yaml")


def config_file(filename: str) -> Path:
    """Path of a file shipped in config/.

    Looks in the installed share directory (ament index) first, then in the
    source tree's config/ folder.
    """
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("robotino_geom_mpc")) / "config")
    except Exception:  # not installed as an ament package, or AMENT_PREFIX_PATH unset
        pass
    candidates.append(Path(__file__).resolve().parents[2] / "config")
    for folder in candidates:
        path = folder / filename
        if path.is_file():
            return path
    raise ParamError(f"'{filename}' not found in {', '.join(map(str, candidates))}")


def default_params_file() -> Path:
    """The default preset (Robotino 3)."""
    return preset_file("robotino3")
