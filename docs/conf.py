"""Sphinx configuration of the documentation site (`make docs`; rosdoc2 reads it through rosdoc2.yaml)."""

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path[:0] = [str(DOCS.parent), str(DOCS / "_ext")]
os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)  # the presets from the source tree or the install

project = "robotino_geom_mpc"
author = "robotino_geom_mpc developers"
copyright = "robotino_geom_mpc developers, Apache-2.0"  # noqa: A001 (Sphinx's name)
release = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "generated",  # docs/_ext/generated.py: parameter reference, scenario list, launch arguments, API pages
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build"]
myst_enable_extensions = ["colon_fence", "dollarmath"]
myst_heading_anchors = 3

# numpydoc docstrings through napoleon; modules import without a ROS install where rclpy and the messages are absent
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True  # Attributes as fields: no second description of a dataclass's fields
autodoc_member_order = "bysource"
autodoc_typehints = "none"
autodoc_default_options = {"members": True, "show-inheritance": False}


def _missing(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is None


_ROS_MODULES = ("rclpy", "nav_msgs", "geometry_msgs", "std_msgs", "sensor_msgs", "trajectory_msgs", "diagnostic_msgs",
                "tf2_msgs", "rosgraph_msgs", "builtin_interfaces", "rcl_interfaces", "std_srvs", "launch", "launch_ros",
                "daqp", "osqp", "quadprog")
autodoc_mock_imports = [m for m in _ROS_MODULES if _missing(m)]

# sphinx-book-theme (the docs extra): the whole toctree with its captions in the sidebar and a wide article column in
# which wide tables and code blocks fit (or scroll in their own box); MathJax typesets myst's $...$ and $$...$$.
# Where it is not installed (a rosdoc2 build with the Sphinx of the distribution) Sphinx's own alabaster.
html_title = "robotino_geom_mpc"
if _missing("sphinx_book_theme"):
    html_theme = "alabaster"
else:
    html_theme = "sphinx_book_theme"
    html_theme_options = {"show_toc_level": 2, "navigation_with_keys": False}
html_static_path: list[str] = []
