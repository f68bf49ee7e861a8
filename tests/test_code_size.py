"""Modules, classes and functions a reader can take in: no module over 500 lines of logic, no class over 500 (its
methods included) and no function over 80, in every package of ``src/swarmloc`` and of the research studies
(``studies/src/swarmloc_studies``). Logic lines are the lines that hold code: blank lines, comments and docstrings
do not count.

What is over a limit today is listed in :data:`OVER` with its present size: the ratchet. A listed item may shrink
but not grow; once it fits its limit (or is gone) the test fails until it is taken off the list, so that the list
stays the honest to-do of the refactor. Nothing new may go over a limit."""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit


SRC = Path(__file__).resolve().parents[1] / "src" / "swarmloc"
STUDIES = Path(__file__).resolve().parents[1] / "studies" / "src" / "swarmloc_studies"
"""The research studies' package, apart from the library but held to the same limits (keys ``swarmloc_studies/...``)."""
MAX_MODULE = 500
MAX_CLASS = 500
MAX_FUNCTION = 80

OVER: dict[str, int] = {}
"""The ratchet: ``"path"`` (a module), ``"path::Class"`` or ``"path::Qual.name"`` (a function or method, nested
names joined by dots) relative to ``src/swarmloc``, with its logic lines today: each may shrink, never grow, and
leaves the list once it fits."""


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
    module, classes, funcs = parts_of(source)
    return module, [(q.rsplit(".", 1)[-1], k) for q, k in funcs]


def parts_of(source: str) -> tuple[int, list[tuple[str, int]], list[tuple[str, int]]]:
    """Logic lines of a module, of each class and of each function, the last two as ``(qualified name, lines)`` in
    source order (nested names joined by dots; a name defined twice in one scope gets ``#2``, ``#3``...)."""
    code = logic_lines(source)
    classes: list[tuple[str, int]] = []
    funcs: list[tuple[str, int]] = []
    seen: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                name = prefix + child.name
                seen[name] = seen.get(name, 0) + 1
                if seen[name] > 1:
                    name = f"{name}#{seen[name]}"
                lines = len([n for n in range(child.lineno, child.end_lineno + 1) if n in code])
                (classes if isinstance(child, ast.ClassDef) else funcs).append((name, lines))
                visit(child, name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return len(code), classes, funcs


def measure(path: Path) -> dict[str, tuple[int, int]]:
    """Every module, class and function of one file: ``{key: (logic lines, limit)}`` with :data:`OVER`'s keys."""
    rel = _key(path)
    module, classes, funcs = parts_of(path.read_text())
    out = {rel: (module, MAX_MODULE)}
    out.update({f"{rel}::{q}": (k, MAX_CLASS) for q, k in classes})
    out.update({f"{rel}::{q}": (k, MAX_FUNCTION) for q, k in funcs})
    return out


def _key(path: Path) -> str:
    """A module's key: its path relative to ``src/swarmloc``, or ``swarmloc_studies/...`` for a study."""
    return path.relative_to(SRC).as_posix() if path.is_relative_to(SRC) else path.relative_to(STUDIES.parent).as_posix()


FILES = sorted(SRC.rglob("*.py")) + sorted(STUDIES.rglob("*.py"))


def everything() -> dict[str, tuple[int, int]]:
    """:func:`measure` of every module of ``src/swarmloc`` and of the studies' package."""
    out: dict[str, tuple[int, int]] = {}
    for path in FILES:
        out.update(measure(path))
    return out


def ratchet(measured: dict[str, tuple[int, int]], over: dict[str, int]) -> dict[str, dict[str, object]]:
    """What breaks the rule in ``measured`` (:func:`measure`'s form) against the list ``over``: ``new`` (over a limit
    and not listed), ``grown`` (larger than listed: ``(listed, now)``)."""
    big = {key: size for key, (size, limit) in measured.items() if size > limit}
    return {
        "new": {key: size for key, size in big.items() if key not in over},
        "grown": {key: (over[key], size) for key, size in big.items() if key in over and size > over[key]},
    }


def stale(measured: dict[str, tuple[int, int]], over: dict[str, int]) -> dict[str, object]:
    """Items of ``over`` to take off the list: ``gone`` (no longer in ``measured``), ``fits`` (within the limit)."""
    return {
        "gone": sorted(key for key in over if key not in measured),
        "fits": {key: measured[key][0] for key in over if key in measured and measured[key][0] <= measured[key][1]},
    }


@pytest.mark.parametrize("path", FILES, ids=_key)
def test_modules_classes_and_functions_fit_a_reader(path: Path) -> None:
    """Over its limit: only an item of :data:`OVER`, and no larger than listed there."""
    bad = ratchet(measure(path), OVER)
    assert not bad["new"], f"over the limits (module {MAX_MODULE}, class {MAX_CLASS}, function {MAX_FUNCTION}): {bad}"
    assert not bad["grown"], f"grown beyond the size listed in OVER (listed, now): {bad}"


def test_the_ratchet_lists_only_what_is_still_over() -> None:
    """Each item of :data:`OVER` still exists and is still over its limit: one that fits now leaves the list."""
    old = stale(everything(), OVER)
    assert not old["gone"] and not old["fits"], f"take these off OVER: {old}"


def test_the_ratchet_refuses_new_grown_and_stale_items() -> None:
    measured = {"m.py": (10, 500), "m.py::f": (90, 80), "m.py::g": (85, 80), "m.py::h": (81, 80), "m.py::k": (70, 80)}
    over = {"m.py::f": 90, "m.py::g": 84, "m.py::k": 82, "x.py::gone": 100}
    assert ratchet(measured, over) == {"new": {"m.py::h": 81}, "grown": {"m.py::g": (84, 85)}}
    assert stale(measured, over) == {"gone": ["x.py::gone"], "fits": {"m.py::k": 70}}
    assert ratchet({"m.py::f": (89, 80)}, {"m.py::f": 90}) == {"new": {}, "grown": {}}  # shrinking is allowed


def test_the_counter_counts_logic_not_docstrings_or_comments() -> None:
    src = '"""Doc\nstring."""\n\n# comment\ndef f(x):\n    """Doc."""\n    y = (x +\n         1)\n    return y\n'
    assert sorted(logic_lines(src)) == [5, 7, 8, 9]
    module, funcs = sizes_of(src)
    assert module == 4 and funcs == [("f", 4)]


def test_classes_count_their_methods_and_names_are_qualified() -> None:
    src = (
        "class A:\n"
        '    """Doc."""\n'
        "    x = 1\n"
        "\n"
        "    def f(self):\n"
        "        def g():\n"
        "            return 1\n"
        "        return g()\n"
        "\n"
        "    def f(self):  # redefined\n"
        "        return 2\n"
    )
    module, classes, funcs = parts_of(src)
    assert module == 8
    assert classes == [("A", 8)]
    assert funcs == [("A.f", 4), ("A.f.g", 2), ("A.f#2", 2)]
