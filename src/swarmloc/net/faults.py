"""Injected network faults: message loss, delay, reordering, duplicates (on every message a node sends), and
process faults that ``swarmloc team`` applies (a node killed and restarted, a late joiner).

Spec (``--faults``), comma-separated ``key=value``::

    loss=0.2        drop each outgoing message with probability 0.2 (0..0.5)
    delay=0.5       delay each outgoing message by U(0, 0.5) s (0..1)
    reorder=0.1     hold a message back 20 ms longer with probability 0.1 (so later ones overtake it)
    dup=0.05        send a message twice with probability 0.05
    kill=2@10       kill robot 2's process when its source reaches 10 s after the start, restart it at once
    late=3@5        start robot 3's process once the others have read 5 s of their sources
    seed=0          random seed of the link faults (each robot draws from its own stream)

Queries, answers, pushed revisions and pairwise updates are all subject to the link faults; published beliefs and
progress messages are not (they are the measurement apparatus of the run, not the estimator's traffic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Faults", "parse_faults"]


@dataclass(frozen=True)
class Faults:
    loss: float = 0.0
    delay: float = 0.0
    reorder: float = 0.0
    dup: float = 0.0
    kill: tuple[int, float] | None = None
    late: tuple[int, float] | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for name, hi in (("loss", 0.5), ("delay", 1.0), ("reorder", 1.0), ("dup", 1.0)):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and 0 <= v <= hi):
                raise ValueError(f"faults: {name} must be a number in [0, {hi}], got {v!r}")

    @property
    def link(self) -> bool:
        """True when any link fault is on."""
        return bool(self.loss or self.delay or self.reorder or self.dup)

    def to_spec(self) -> str:
        parts = [f"{k}={getattr(self, k):g}" for k in ("loss", "delay", "reorder", "dup") if getattr(self, k)]
        for k in ("kill", "late"):
            v = getattr(self, k)
            if v is not None:
                parts.append(f"{k}={v[0]}@{v[1]:g}")
        if self.seed:
            parts.append(f"seed={self.seed}")
        return ",".join(parts)

    def plan(self, robot: int) -> LinkFaults:
        return LinkFaults(self, robot)


class LinkFaults:
    """Per-robot draws: ``schedule()`` -> the delays [s] at which to send copies of one message (empty: lost)."""

    def __init__(self, faults: Faults, robot: int) -> None:
        self.f = faults
        self.rng = np.random.default_rng([faults.seed, robot])
        self.lost = 0
        self.duplicated = 0
        self.delayed = 0

    def schedule(self) -> list[float]:
        f, rng = self.f, self.rng
        if f.loss and rng.random() < f.loss:
            self.lost += 1
            return []
        copies = 2 if f.dup and rng.random() < f.dup else 1
        if copies == 2:
            self.duplicated += 1
        out = []
        for _ in range(copies):
            d = rng.uniform(0.0, f.delay) if f.delay else 0.0
            if f.reorder and rng.random() < f.reorder:
                d += 0.02
            out.append(d)
        if any(out):
            self.delayed += 1
        return out


def _robot_at(key: str, v: str) -> tuple[int, float]:
    r, sep, t = v.partition("@")
    try:
        out = (int(r), float(t))
    except ValueError:
        out = None
    if not sep or out is None or not math.isfinite(out[1]) or out[1] < 0:
        raise ValueError(f"faults: {key} takes ROBOT@SECONDS (e.g. {key}=2@10), got {v!r}")
    return out


def parse_faults(spec: str | None) -> Faults:
    """Parse a ``--faults`` spec (see the module docstring); raises ValueError naming the bad part."""
    if not spec:
        return Faults()
    kw: dict = {}
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        key, sep, v = part.partition("=")
        if not sep:
            raise ValueError(f"faults: expected key=value, got {part!r}")
        if key in ("loss", "delay", "reorder", "dup"):
            try:
                kw[key] = float(v)
            except ValueError:
                raise ValueError(f"faults: {key} must be a number, got {v!r}") from None
        elif key in ("kill", "late"):
            kw[key] = _robot_at(key, v)
        elif key == "seed":
            try:
                kw[key] = int(v)
            except ValueError:
                raise ValueError(f"faults: seed must be an integer, got {v!r}") from None
        else:
            raise ValueError(f"faults: unknown key {key!r} (loss, delay, reorder, dup, kill, late, seed)")
    return Faults(**kw)
