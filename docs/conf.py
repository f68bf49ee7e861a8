"""Sphinx configuration of swarmloc's documentation.

Why Sphinx with MyST and autodoc: the docstrings already use Sphinx's roles (``:class:``, ``:func:``, ``:mod:``,
``:data:``) and numpy-style sections, so Sphinx renders them as written; MyST lets the pages themselves be Markdown.
Build: ``python -m sphinx -W --keep-going -b html docs docs/_build/html`` (what CI runs; warnings are errors).
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# document this checkout's code (the library and its research studies), not another installed copy
sys.path[:0] = [str(ROOT / "src"), str(ROOT / "studies" / "src")]
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

project = "swarmloc"
author = "the swarmloc authors"
copyright = "the swarmloc authors"  # noqa: A001 (Sphinx's name)

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx.ext.intersphinx",
    "project_docstrings",  # docs/_ext: the docstrings' "name: description" entries read as numpy sections
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store"]

# Markdown: `$...$` maths, `:::` fences, definition lists; headings get anchors for [text](page.md#anchor) links.
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# The docstrings are numpy style ("Parameters\n----------"); Google style is not used.
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False

autodoc_default_options = {"show-inheritance": True, "member-order": "bysource"}
autodoc_typehints = "description"
# The optional extras (gtsam, jax, numba, foxglove) are documented without them where they are not installed.
autodoc_mock_imports = [name for name in ("gtsam", "jax", "numba", "foxglove") if not importlib.util.find_spec(name)]

# Links into Python's and numpy's documentation need their inventories from the network, which CI may not have
# (an unreachable inventory is a warning, so an error under -W): on only with SWARMLOC_DOCS_INTERSPHINX=1.
intersphinx_mapping = {}
if os.environ.get("SWARMLOC_DOCS_INTERSPHINX") == "1":
    intersphinx_mapping = {
        "python": ("https://docs.python.org/3", None),
        "numpy": ("https://numpy.org/doc/stable", None),
    }
intersphinx_timeout = 5

html_theme = "furo"
html_title = "swarmloc"


def _generated() -> None:
    """Pages made from the code's one declaration of a thing: the ROS node's parameters (``ros2.md`` includes it) and
    the configuration's keys (``configuration.md``)."""
    from swarmloc.config import config_markdown
    from swarmloc.ros.params import params_markdown

    out = ROOT / "docs" / "_generated"
    out.mkdir(exist_ok=True)
    for name, text in (("ros_params.md", params_markdown()), ("config_keys.md", config_markdown())):
        path = out / name
        if not path.exists() or path.read_text() != text:  # rewritten only when it changed: no needless rebuild
            path.write_text(text)


_generated()
