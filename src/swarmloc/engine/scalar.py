"""Straight-line scalar code generated from the structure-of-arrays formulas of :mod:`swarmloc.engine.soa`.

The formulas are traced once with symbolic entries (:class:`_Sym`): every operation becomes one assignment of a
scalar temporary, constants (the Jacobians' zeros and ones) are folded in as soa folds them, the noise model's
coefficients are an argument (one compiled prediction for every model), and the result is the source of a plain
Python function of floats that numba compiles to register code.
So the numba backend runs the very formulas of the numpy and jax backends.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from itertools import accumulate
from typing import Any

from swarmloc.engine import soa
from swarmloc.motion import UnicycleNoise


class _Builder:
    def __init__(self) -> None:
        self.lines: list[str] = []
        self.wheres: dict[str, tuple[str, str, str]] = {}
        """Temporaries made by ``where``: name -> (condition, value if true, value if false)."""

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


def _operator(op: str, reflected: bool = False) -> Callable[[_Sym, Any], _Sym]:
    """:class:`_Sym`'s method for the binary operator ``op`` (``reflected``: the ``__r*__`` one, ``other op self``)."""

    def method(self: _Sym, o: Any) -> _Sym:
        return self._op(op, o, reflected)

    return method


class _Sym:
    """A traced scalar: operations emit assignments."""

    __slots__ = ("name", "b")
    __hash__ = object.__hash__

    def __init__(self, name: str, b: _Builder) -> None:
        self.name, self.b = name, b

    def _op(self, op: str, other: Any, rev: bool = False) -> _Sym:
        a, c = (other, self) if rev else (self, other)
        return self.b.emit(f"{_s(a)} {op} {_s(c)}")

    __add__, __radd__ = _operator("+"), _operator("+", True)
    __sub__, __rsub__ = _operator("-"), _operator("-", True)
    __mul__, __rmul__ = _operator("*"), _operator("*", True)
    __truediv__, __rtruediv__ = _operator("/"), _operator("/", True)
    __lt__, __gt__, __and__ = _operator("<"), _operator(">"), _operator("and")
    __eq__ = _operator("==")  # type: ignore[assignment]

    def __neg__(self) -> _Sym:
        return self.b.emit(f"-{self.name}")

    def __abs__(self) -> _Sym:
        return self.b.emit(f"abs({self.name})")


class _XP:
    """The array namespace soa expects, emitting scalar code."""

    def __init__(self, b: _Builder) -> None:
        self.b = b

    def where(self, c: Any, a: Any, d: Any) -> _Sym:
        sym = self.b.emit(f"{_s(a)} if {_s(c)} else {_s(d)}")
        self.b.wheres[sym.name] = (_s(c), _s(a), _s(d))
        return sym

    def _f(self, fn: str, *args: Any) -> _Sym:
        return self.b.emit(f"{fn}({', '.join(_s(a) for a in args)})")

    def cos(self, a: Any) -> _Sym:
        return self._f("math.cos", a)

    def sin(self, a: Any) -> _Sym:
        return self._f("math.sin", a)

    def sqrt(self, a: Any) -> _Sym:
        return self._f("math.sqrt", a)

    def arctan2(self, a: Any, c: Any) -> _Sym:
        return self._f("math.atan2", a, c)

    def mod(self, a: Any, c: Any) -> _Sym:
        # np.mod(a, c) is a itself for 0 < a < c (fmod is exact): skip the call there (same bits)
        return self.b.emit(f"{_s(a)} if 0.0 < {_s(a)} < {_s(c)} else np.mod({_s(a)}, {_s(c)})")

    def abs(self, a: Any) -> _Sym:
        return self._f("abs", a)

    def isfinite(self, a: Any) -> _Sym:
        return self._f("math.isfinite", a)


_TEMP = re.compile(r"\bt\d+\b")


def _branches(b: _Builder, outs: list[str]) -> list[str]:
    """The traced lines with every ``where`` turned into an ``if``/``else`` that computes only the branch taken.

    A temporary moves into a branch when every use of it is inside that branch (its *exclusive cone*); the same
    expressions are evaluated in the same order, so the results are the same bits, without the work of the branch
    not taken (the trigonometric forms of the odometry increment where its Taylor series is used, and back)."""
    lines = [ln.strip() for ln in b.lines]
    names = [ln.split(" = ", 1)[0] for ln in lines]
    index = {n: i for i, n in enumerate(names)}
    deps = [[index[d] for d in _TEMP.findall(ln.split(" = ", 1)[1]) if d in index] for ln in lines]
    users: list[set[int]] = [set() for _ in lines]
    for i, ds in enumerate(deps):
        for d in ds:
            users[d].add(i)
    pinned = {index[o] for o in outs if o in index}  # returned: computed on every path
    owner: dict[int, tuple[int, bool]] = {}  # line -> (where line, branch); the innermost where wins
    for w, n in enumerate(names):
        if n not in b.wheres:
            continue
        cond, yes, no = b.wheres[n]
        for side, root in ((True, yes), (False, no)):
            if root not in index or index[root] in pinned or users[index[root]] != {w}:
                continue
            cone = {index[root]}
            grew = True
            while grew:
                grew = False
                for m in list(cone):
                    for d in deps[m]:
                        if d not in cone and d not in pinned and names[d] != cond and users[d] <= cone | {w}:
                            cone.add(d)
                            grew = True
            for m in cone:
                if m not in owner or owner[m][0] > w:
                    owner[m] = (w, side)

    def emit(members: list[int], pad: str) -> list[str]:
        out = []
        for i in members:
            if names[i] in b.wheres:
                cond, yes, no = b.wheres[names[i]]
                inner = {side: [m for m in range(i) if owner.get(m) == (i, side)] for side in (True, False)}
                out.append(f"{pad}if {cond}:")
                out += emit(inner[True], pad + "    ") + [f"{pad}    {names[i]} = {yes}"]
                out.append(f"{pad}else:")
                out += emit(inner[False], pad + "    ") + [f"{pad}    {names[i]} = {no}"]
            else:
                out.append(pad + lines[i])
        return out

    return emit([i for i in range(len(lines)) if i not in owner], "    ")


def _generate(name: str, n_in: int, body: Callable[[_XP, list[_Sym]], list[soa.Entry]], packed: int = 0) -> str:
    """Source of ``name(a0, .., a{n_in - 1}[, q])``: ``body`` traced on the arguments; with ``packed``, a last
    argument ``q`` holds that many more (a tuple, unpacked first), which ``body`` gets after the others."""
    b = _Builder()
    args = [_Sym(f"a{i}", b) for i in range(n_in + packed)]
    outs = [_s(o) for o in body(_XP(b), args)]
    names = [a.name for a in args]
    head = [f"def {name}({', '.join(names[:n_in] + ['q'] * bool(packed))}):"]
    if packed:
        head.append(f"    {', '.join(names[n_in:])} = q")
    return "\n".join([*head, *_branches(b, outs), f"    return ({', '.join(outs)},)"]) + "\n"


def predict_source() -> str:
    """``predict(x0, x1, x2, p00, p01, p02, p11, p12, p22, v, w, dt, q) -> (x, P upper triangle)``, ``q`` the noise
    model's coefficients (:func:`swarmloc.engine.replay_io.noise_tuple`), read at run time: one compiled prediction
    serves every noise model, with the operations (and bits) of a model's coefficients written in as constants."""

    def body(xp: _XP, a: list[_Sym]) -> list[soa.Entry]:
        coefficients: list[Any] = a[12:]  # symbolic, in the fields' order: traced as floats
        noise = UnicycleNoise(*coefficients)
        xs, ps = soa.predict(xp, tuple(a[0:3]), tuple(a[3:9]), a[9], a[10], a[11], noise)
        return [*xs, *ps]

    return _generate("predict", 12, body, packed=len(dataclasses.fields(UnicycleNoise)))


def _update_source(name: str, update: Callable[..., soa.Updated], sizes: tuple[int, ...]) -> str:
    """Source of ``name(x(3), P(6), *blocks) -> (x+(3), P+(6), nis, ok and positive definite)``: :mod:`soa`'s
    ``update(xp, x, P, *blocks)`` with blocks of ``sizes`` entries."""
    ends = list(accumulate((3, 6, *sizes)))

    def body(xp: _XP, a: list[_Sym]) -> list[soa.Entry]:
        xs, ps, nis, ok = update(xp, *(tuple(a[i:j]) for i, j in zip([0, *ends], ends, strict=False)))
        return [*xs, *ps, nis, ok & soa.positive_definite(xp, ps)]

    return _generate(name, ends[-1], body)


def pose_source() -> str:
    """``pose(x(3), P(6), xk(3), Pk(6), z(3), R(6)) -> (x+(3), P+(6), nis, ok and positive definite)``."""
    return _update_source("pose", soa.pose_update, (3, 6, 3, 6))


def absolute_source() -> str:
    """``absolute(x(3), P(6), z(3), R(6)) -> (x+(3), P+(6), nis, ok and positive definite)``."""
    return _update_source("absolute", soa.absolute_update, (3, 6))


def landmark_source() -> str:
    """``landmark(x(3), P(6), lk(2), L(3), z(2), R(3)) -> (x+(3), P+(6), nis, ok and positive definite)``."""
    return _update_source("landmark", soa.landmark_update, (2, 3, 2, 3))
