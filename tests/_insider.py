"""A lying insider for the tests: a node whose every message is shifted 100 m on its way out (its beliefs and states
in answers, its pairwise updates, its broadcasts' innovations), used in process (tests/test_insider.py) and as a
network process with its own valid key (tests/net_insider.py)."""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from swarmloc.messages import BeliefAnswer, Message, RdlState, RdlUpdate, TeamUpdate, flat

SHIFT = 100.0
"""[m] How far the insider moves what it tells."""


def lie(m: Message, shift: float = SHIFT) -> Message:
    """``m`` with its numbers moved ``shift`` metres along x: a belief's mean (world frame), a state's or an update's
    ``x``, a broadcast's innovation ``r`` (first component, so ``nu = S^-1 r`` moves by ``S^-1 (shift, 0, ...)``)."""
    if isinstance(m, BeliefAnswer) and m.found:
        mean = list(m.mean)
        mean[3 if m.group == "SE3" else 2] += shift
        return msgspec.structs.replace(m, mean=tuple(mean))
    if (isinstance(m, RdlState) and m.found and len(m.x) == 3) or (isinstance(m, RdlUpdate) and not m.empty):
        return msgspec.structs.replace(m, x=(m.x[0] + shift, *m.x[1:]))
    if isinstance(m, TeamUpdate) and not m.empty:
        r = np.zeros(m.m)
        r[0] = shift
        nu = np.array(m.nu) + np.reshape(m.Sinv, (m.m, m.m)) @ r
        return msgspec.structs.replace(m, nu=flat(nu))
    return m


def lying(cls: type) -> type:
    """A subclass of the node class ``cls`` that sends every message through :func:`lie`."""

    def step(self: Any, item: Any) -> list[Message]:
        return [lie(m) for m in cls.step(self, item)]

    def expire(self: Any, before: float | None = None) -> list[Message]:
        return [lie(m) for m in cls.expire(self, before)]

    return type(f"Lying{cls.__name__}", (cls,), {"step": step, "expire": expire})
