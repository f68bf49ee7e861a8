"""Settings declared once, as the typed fields of a class with one attribute docstring each (the sections of
:class:`swarmloc.config.Config`, :class:`swarmloc.ros.params.RosParams`): their docstrings read back, and a
Markdown table of them, for the listings the command line prints and the tables the documentation includes.

The convention: the docstring right below a field is its meaning, one sentence, starting with its unit in brackets
where it has one (``[Hz] rate of the outputs.``); Sphinx renders the same docstrings in the API pages.
"""

from __future__ import annotations

import ast
import inspect
import textwrap
from collections.abc import Iterable, Sequence

__all__ = ["attribute_docs", "markdown_table"]


def attribute_docs(cls: type) -> dict[str, str]:
    """``{field: docstring}`` of the class's annotated fields that have one, each on one line (read from the class's
    source; empty where the source cannot be read)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    docs: dict[str, str] = {}
    for a, b in zip(body, body[1:], strict=False):
        if (
            isinstance(a, ast.AnnAssign)
            and isinstance(a.target, ast.Name)
            and isinstance(b, ast.Expr)
            and isinstance(b.value, ast.Constant)
            and isinstance(b.value.value, str)
        ):
            docs[a.target.id] = " ".join(b.value.value.split())
    return docs


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table (``|``-separated rows); a ``|`` inside a cell is escaped (``\\|``), so it reads as text."""
    lines = [header, ["---"] * len(header), *rows]
    return "\n".join("| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in lines) + "\n"
