"""Straight-line scalar code generated from the structure-of-arrays formulas of :mod:`swarmloc.engine.soa`.

The formulas are traced once with symbolic entries (:class:`_Sym`): every operation becomes one assignment of a
scalar temporary, constants (the Jacobians' zeros and ones, the noise coefficients) are folded in as soa folds
them, and the result is the source of a plain Python function of floats that numba compiles to register code.
So the numba backend runs the very formulas of the numpy and jax backends.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from swarmloc.engine import soa
from swarmloc.motion import UnicycleNoise


class _Builder:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def emit(self, expr: str) -> _Sym:
        name = f"t{len(self.lines)}"
        self.lines.append(f"    {name} = {expr}")
        return _Sym(name, self)


def _s(a: Any) -> str:
    if isinstance(a, _Sym):
        return a.name
    if isinstance(a, bool):
        return repr(a)
    return repr(float(a))


class _Sym:
    """A traced scalar: operations emit assignments."""

    __slots__ = ("name", "b")
    __hash__ = object.__hash__

    def __init__(self, name: str, b: _Builder) -> None:
        self.name, self.b = name, b

    def _op(self, op: str, other: Any, rev: bool = False) -> _Sym:
        a, c = (other, self) if rev else (self, other)
        return self.b.emit(f"{_s(a)} {op} {_s(c)}")

    def __add__(self, o: Any) -> _Sym:
        return self._op("+", o)

    def __radd__(self, o: Any) -> _Sym:
        return self._op("+", o, True)

    def __sub__(self, o: Any) -> _Sym:
        return self._op("-", o)

    def __rsub__(self, o: Any) -> _Sym:
        return self._op("-", o, True)

    def __mul__(self, o: Any) -> _Sym:
        return self._op("*", o)

    def __rmul__(self, o: Any) -> _Sym:
        return self._op("*", o, True)

    def __truediv__(self, o: Any) -> _Sym:
        return self._op("/", o)

    def __rtruediv__(self, o: Any) -> _Sym:
        return self._op("/", o, True)

    def __neg__(self) -> _Sym:
        return self.b.emit(f"-{self.name}")

    def __abs__(self) -> _Sym:
        return self.b.emit(f"abs({self.name})")

    def __lt__(self, o: Any) -> _Sym:
        return self._op("<", o)

    def __gt__(self, o: Any) -> _Sym:
        return self._op(">", o)

    def __eq__(self, o: Any) -> _Sym:  # type: ignore[override]
        return self._op("==", o)

    def __and__(self, o: Any) -> _Sym:
        return self._op("and", o)


class _XP:
    """The array namespace soa expects, emitting scalar code."""

    def __init__(self, b: _Builder) -> None:
        self.b = b

    def where(self, c: Any, a: Any, d: Any) -> _Sym:
        return self.b.emit(f"{_s(a)} if {_s(c)} else {_s(d)}")

    def _f(self, fn: str, *args: Any) -> _Sym:
        return self.b.emit(f"{fn}({', '.join(_s(a) for a in args)})")

    def cos(self, a: Any) -> _Sym:
        return self._f("math.cos", a)

    def sin(self, a: Any) -> _Sym:
        return self._f("math.sin", a)

    def arctan2(self, a: Any, c: Any) -> _Sym:
        return self._f("math.atan2", a, c)

    def mod(self, a: Any, c: Any) -> _Sym:
        return self._f("np.mod", a, c)

    def abs(self, a: Any) -> _Sym:
        return self._f("abs", a)

    def isfinite(self, a: Any) -> _Sym:
        return self._f("math.isfinite", a)


def _generate(name: str, n_in: int, body: Callable[[Any, list[_Sym]], list[Any]]) -> str:
    b = _Builder()
    args = [_Sym(f"a{i}", b) for i in range(n_in)]
    outs = body(_XP(b), args)
    head = f"def {name}({', '.join(a.name for a in args)}):"
    return "\n".join([head, *b.lines, f"    return ({', '.join(_s(o) for o in outs)},)"]) + "\n"


def predict_source(noise: UnicycleNoise) -> str:
    """``predict(x0, x1, x2, p00, p01, p02, p11, p12, p22, v, w, dt) -> (x, P upper triangle)``."""

    def body(xp: Any, a: list) -> list:
        xs, ps = soa.predict(xp, tuple(a[0:3]), tuple(a[3:9]), a[9], a[10], a[11], noise)
        return [*xs, *ps]

    return _generate("predict", 12, body)


def pose_source() -> str:
    """``pose(x(3), P(6), xk(3), Pk(6), z(3), R(6)) -> (x+(3), P+(6), nis, ok and positive definite)``."""

    def body(xp: Any, a: list) -> list:
        xs, ps, nis, ok = soa.pose_update(xp, tuple(a[0:3]), tuple(a[3:9]), tuple(a[9:12]), tuple(a[12:18]),
                                          tuple(a[18:21]), tuple(a[21:27]))  # fmt: skip
        return [*xs, *ps, nis, ok & soa.positive_definite(xp, ps)]

    return _generate("pose", 27, body)


def absolute_source() -> str:
    """``absolute(x(3), P(6), z(3), R(6)) -> (x+(3), P+(6), nis, ok and positive definite)``."""

    def body(xp: Any, a: list) -> list:
        xs, ps, nis, ok = soa.absolute_update(xp, tuple(a[0:3]), tuple(a[3:9]), tuple(a[9:12]), tuple(a[12:18]))
        return [*xs, *ps, nis, ok & soa.positive_definite(xp, ps)]

    return _generate("absolute", 18, body)
