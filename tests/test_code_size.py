"""Modules and functions a reader can take in: no module over 500 lines of logic and no function over 80 lines in
the runtime packages (``node``, ``estimators``, ``engine``, ``net``, ``runner``). Logic lines are the lines that hold
code: blank lines, comments and docstrings do not count."""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit


SRC = Path(__file__).resolve().parents[1] / "src" / "swarmloc"
PACKAGES = ("node", "estimators", "engine", "net", "runner")
MAX_MODULE = 500
MAX_FUNCTION = 80


def logic_lines(source: str) -> set[int]:
    """Line numbers that hold code (not blank, not only a comment, not inside a docstring)."""
    tree = ast.parse(source)
    doc: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if (
                isinstance(first, ast.Expr)
                and isinstance(first.value, ast.Constant)
                and isinstance(first.value.value, str)
            ):
                doc.update(range(first.lineno, first.end_lineno + 1))
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            doc.update(range(node.lineno, node.end_lineno + 1))  # attribute docstrings
    code: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type not in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
                            tokenize.ENDMARKER):  # fmt: skip
            code.update(range(tok.start[0], tok.end[0] + 1))
    return code - doc


def sizes(path: Path) -> tuple[int, list[tuple[str, int]]]:
    """Logic lines of a module and of each of its functions (methods included), ``(name, lines)``."""
    return sizes_of(path.read_text())


def sizes_of(source: str) -> tuple[int, list[tuple[str, int]]]:
    """:func:`sizes` of a module's source text."""
    code = logic_lines(source)
    funcs = [
        (node.name, len([n for n in range(node.lineno, node.end_lineno + 1) if n in code]))
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
    ]
    return len(code), funcs


FILES = sorted(p for pkg in PACKAGES for p in (SRC / pkg).rglob("*.py"))


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(SRC)))
def test_module_and_functions_fit_a_reader(path: Path) -> None:
    module, funcs = sizes(path)
    assert module <= MAX_MODULE, f"{path.relative_to(SRC)}: {module} lines of logic (at most {MAX_MODULE})"
    long = [(n, k) for n, k in funcs if k > MAX_FUNCTION]
    assert not long, f"{path.relative_to(SRC)}: functions over {MAX_FUNCTION} lines: {long}"


def test_the_counter_counts_logic_not_docstrings_or_comments() -> None:
    src = '"""Doc\nstring."""\n\n# comment\ndef f(x):\n    """Doc."""\n    y = (x +\n         1)\n    return y\n'
    assert sorted(logic_lines(src)) == [5, 7, 8, 9]
    module, funcs = sizes_of(src)
    assert module == 4 and funcs == [("f", 4)]
