"""One angle wrap: :func:`swarmloc.lie.wrap_angle`, to (-pi, pi]; no other module writes a wrap of its own."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from swarmloc.lie import wrap_angle

pytestmark = pytest.mark.unit

SRC = Path(__file__).resolve().parents[1] / "src" / "swarmloc"
OWN_FORM = {
    "lie/se2.py": "wrap_angle itself",
    "sensors/planar.py": "the measurement models over an array namespace (numpy, numba on scalars, jax.numpy traced, "
    "numba generated): the engine's kernels and the nodes' models call it",
    "kernels/cartesian.py": "kalman_one, which numba compiles for the rdl replay as the nodes run it plain: "
    "wrap_angle's float form inline (numba cannot call wrap_angle)",
    "sim/lab.py": "np.angle(exp(1j x)) gives -pi at x = -pi: it decides which way a scripted robot turns",
    "association/pmr.py": "angles ordered in [0, 2 pi), not wrapped",
}
"""Modules that keep their own form of a wrap, and why."""


def _mentions_pi(node: ast.AST) -> bool:
    text = ast.unparse(node).lower()
    return "pi" in text or "tau" in text


def _same_args(a: ast.Call, b: ast.Call) -> bool:
    return [ast.unparse(x) for x in a.args] == [ast.unparse(x) for x in b.args]


def wraps(tree: ast.AST) -> list[tuple[int, str]]:
    """``(line, source)`` of each hand-written wrap: ``a % (2 pi)``, ``mod / fmod / remainder(a, 2 pi)``,
    ``angle(exp(1j a))``, ``atan2(sin a, cos a)``."""
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mod) and _mentions_pi(node.right):
            hits.append(node)
        elif isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            args = node.args
            if name in ("mod", "fmod", "remainder") and len(args) == 2 and _mentions_pi(args[1]):
                hits.append(node)
            elif (
                name == "angle" and args and isinstance(args[0], ast.Call) and ast.unparse(args[0].func).endswith("exp")
            ):
                hits.append(node)
            elif (name in ("arctan2", "atan2") and len(args) == 2 and all(isinstance(a, ast.Call) for a in args)
                  and [ast.unparse(a.func).split(".")[-1] for a in args] == ["sin", "cos"]  # type: ignore[attr-defined]
                  and _same_args(args[0], args[1])):  # type: ignore[arg-type]  # fmt: skip
                hits.append(node)
    return [(n.lineno, ast.unparse(n)) for n in hits]  # type: ignore[attr-defined]


def test_the_scanner_finds_each_form_of_wrap():
    for src in ["(a + np.pi) % (2 * np.pi) - np.pi", "math.pi - (math.pi - a) % TAU", "np.mod(a, 2 * np.pi)",
                "np.angle(np.exp(1j * a))", "math.atan2(math.sin(a), math.cos(a))"]:  # fmt: skip
        assert len(wraps(ast.parse(src))) == 1, src
    for src in ["wrap_angle(a)", "i % 2", "math.atan2(w @ np.sin(a), w @ np.cos(a))", "np.sinc(a / (2 * np.pi))"]:
        assert wraps(ast.parse(src)) == [], src


def test_no_module_wraps_angles_by_hand():
    found = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel not in OWN_FORM:
            found += [f"{rel}:{line}: {text}" for line, text in wraps(ast.parse(path.read_text()))]
    assert found == [], "call swarmloc.lie.wrap_angle:\n" + "\n".join(found)


def test_wrap_angle_convention_and_float_path():
    """(-pi, pi]: pi stays, -pi becomes pi; a float (Python or NumPy) gets the bits of the array path."""
    rng = np.random.default_rng(0)
    a = np.concatenate([rng.normal(0, 4, 2000), rng.uniform(-1e4, 1e4, 2000),
                        [math.pi, -math.pi, 0.0, -0.0, 2 * math.pi, 3 * math.pi, -3 * math.pi, 1e-300]])  # fmt: skip
    arr = wrap_angle(a)
    assert np.all((arr > -math.pi) & (arr <= math.pi))
    assert wrap_angle(math.pi) == math.pi and wrap_angle(-math.pi) == math.pi
    py = np.array([wrap_angle(float(x)) for x in a])
    np64 = np.array([wrap_angle(x) for x in a])  # numpy float64 scalars
    assert py.view(np.int64).tolist() == arr.view(np.int64).tolist()
    assert np64.view(np.int64).tolist() == arr.view(np.int64).tolist()
    assert type(wrap_angle(np.float64(1.0))) is np.float64 and wrap_angle(np.array(1.0)).shape == ()
