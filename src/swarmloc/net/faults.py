"""Injected network faults: message loss, delay, reordering, duplicates (on every message a node sends), process
faults that ``swarmloc team`` applies (a node killed and restarted or not, a late joiner), and a robot's clock
that jumps.

Spec (``--faults``), comma-separated ``key=value``::

    loss=0.2        drop each outgoing message with probability 0.2 (0..0.5)
    delay=0.5       delay each outgoing message by U(0, 0.5) s (0..1)
    reorder=0.1     hold a message back 20 ms longer with probability 0.1 (so later ones overtake it)
    dup=0.05        send a message twice with probability 0.05
    kill=2@10       kill robot 2's process (SIGKILL) when its source reaches 10 s after the start, restart it at once
                    from the belief server (--resume)
    killonly=2@10   the same kill, never restarted: the team goes on without robot 2
    late=3@5        start robot 3's process once the others have read 5 s of their sources
    jump=1@10:30    robot 1's clock jumps by +30 s (or back, -30) 10 s after its first stamp: every input it reads
                    from then on is stamped 30 s later than the source says (the node's clock contract decides)
    seed=0          random seed of the link faults (each robot draws from its own stream)

Queries, answers, pushed revisions and pairwise updates are all subject to the link faults; published beliefs and
progress messages are not (they are the measurement apparatus of the run, not the estimator's traffic).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from swarmloc.events import Odometry, OwnEvent

__all__ = ["Faults", "parse_faults"]

log = logging.getLogger("swarmloc.net.process")  # the driver's one logger, whichever part logs


@dataclass(frozen=True)
class Faults:
    loss: float = 0.0
    delay: float = 0.0
    reorder: float = 0.0
    dup: float = 0.0
    kill: tuple[int, float] | None = None
    late: tuple[int, float] | None = None
    seed: int = 0
    restart: bool = True
    """Restart the killed robot (``kill``), or not (``killonly``)."""
    jump: tuple[int, float, float] | None = None
    """``(robot, after [s], shift [s])``: the robot's input stamps from ``after`` s past its first on are shifted."""

    def __post_init__(self) -> None:
        for name, hi in (("loss", 0.5), ("delay", 1.0), ("reorder", 1.0), ("dup", 1.0)):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and 0 <= v <= hi):
                raise ValueError(f"faults: {name} must be a number in [0, {hi}], got {v!r}")
        if self.jump is not None and not (0 < abs(self.jump[2]) <= 3600):
            raise ValueError(f"faults: jump shifts by a non-zero number of seconds within +-3600, got {self.jump[2]!r}")

    @property
    def link(self) -> bool:
        """True when any link fault is on."""
        return bool(self.loss or self.delay or self.reorder or self.dup)

    @property
    def joiner(self) -> int | None:
        """The robot whose process the launcher starts during the run (``late``'s, or ``kill``'s restarted), or None:
        it joins only if the team is still running once it is up."""
        if self.late is not None:
            return self.late[0]
        return self.kill[0] if self.kill is not None and self.restart else None

    def to_spec(self) -> str:
        parts = [f"{k}={getattr(self, k):g}" for k in ("loss", "delay", "reorder", "dup") if getattr(self, k)]
        for k in ("kill", "late"):
            v = getattr(self, k)
            if v is not None:
                parts.append(f"{'killonly' if k == 'kill' and not self.restart else k}={v[0]}@{v[1]:g}")
        if self.jump is not None:
            parts.append(f"jump={self.jump[0]}@{self.jump[1]:g}:{self.jump[2]:+g}")
        if self.seed:
            parts.append(f"seed={self.seed}")
        return ",".join(parts)

    def plan(self, robot: int) -> LinkFaults:
        return LinkFaults(self, robot)

    def node_faults(self) -> Faults:
        """What a node process applies itself: the link faults and the clock jump (not the launcher's kill, late)."""
        return Faults(loss=self.loss, delay=self.delay, reorder=self.reorder, dup=self.dup, seed=self.seed,
                      jump=self.jump)  # fmt: skip

    def jumped(self, robot: int, events: Sequence[OwnEvent]) -> list[OwnEvent]:
        """``robot``'s own ``events`` (stamp order) as its clock gives them with the ``jump`` fault: from ``after``
        s past the first stamp on, every stamp shifted by ``shift`` s (unchanged without a jump for this robot)."""
        if self.jump is None or self.jump[0] != robot or not events:
            return list(events)
        _, after, shift = self.jump
        t_jump = min(float(e.stamp) for e in events) + after
        return [_shifted(e, shift) if float(e.stamp) >= t_jump else e for e in events]


def _shifted(e: OwnEvent, dt: float) -> OwnEvent:
    if isinstance(e, Odometry):
        return replace(e, t0=e.t0 + dt, t1=e.t1 + dt)
    return replace(e, t=e.t + dt)


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


class FaultySender:
    """Robot ``robot``'s sends as its link faults ``link`` say (None: none): lost, delayed (waiting on ``timers``
    until :meth:`run_timers` finds them due), duplicated; counted in ``counts`` (``sent``, ``lost``, ``delayed``,
    ``duplicated``, ``send_failed``). Other delayed work may wait on the same timers (:meth:`later`)."""

    def __init__(self, link: LinkFaults | None, counts: Counter[str], robot: int) -> None:
        self.link, self.counts, self.robot = link, counts, robot
        self.timers: list[tuple[float, int, Callable[[], None]]] = []
        """``(due, id, fn)``: delayed sends and other timed work (a heap)."""
        self._ids = itertools.count()  # tie-breakers

    def later(self, due: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` once monotonic time ``due`` has come (:meth:`run_timers`)."""
        heapq.heappush(self.timers, (due, next(self._ids), fn))

    def faulty(self, send: Callable[[], None], finish: Callable[[], None] | None = None) -> int:
        """Send now, or as the link faults say (lost, delayed, duplicated); returns the copies sent. ``finish`` runs
        once the last copy is sent (at once if every copy is lost): closing the Zenoh query a reply answers, so that
        a duplicate reply goes out on a query still open. A copy that fails to go out is counted (``send_failed``)
        and logged; it never raises into the caller's loop."""
        delays = [0.0] if self.link is None else self.link.schedule()
        if not delays:
            self.counts["lost"] += 1
        elif len(delays) > 1:
            self.counts["duplicated"] += 1
        left = [len(delays)]

        def one() -> None:
            try:
                send()
            except Exception as exc:  # noqa: BLE001 - e.g. the asker is gone: a missing answer, not a crash
                self.send_failed(exc)
            left[0] -= 1
            if left[0] == 0 and finish is not None:
                finish()

        if not delays and finish is not None:
            finish()
        for d in delays:
            self.counts["sent"] += 1
            if d <= 0:
                one()
            else:
                self.counts["delayed"] += 1
                self.later(time.monotonic() + d, one)
        return len(delays)

    def send_failed(self, exc: Exception) -> None:
        """Count a message that could not go out (``send_failed``) and log the first."""
        self.counts["send_failed"] += 1
        level = logging.WARNING if self.counts["send_failed"] == 1 else logging.DEBUG
        log.log(level, "robot %s: a send failed (counted send_failed): %s: %s", self.robot, type(exc).__name__, exc)

    def run_timers(self) -> float:
        """Send (run) what is due; seconds until the next timer (inf if none)."""
        now = time.monotonic()
        while self.timers and self.timers[0][0] <= now:
            _, _, fn = heapq.heappop(self.timers)
            try:
                fn()
            except Exception as exc:  # noqa: BLE001 - a delayed send never raises into the loop (see faulty)
                self.send_failed(exc)
        return self.timers[0][0] - now if self.timers else math.inf


def _read(convert: Callable[[str], Any], v: str, message: str) -> Any:
    """``convert(v)``, or ValueError(``message``) where it raises ValueError."""
    try:
        return convert(v)
    except ValueError:
        raise ValueError(message) from None


def _robot_at(key: str, v: str) -> tuple[int, float]:
    r, sep, t = v.partition("@")
    message = f"faults: {key} takes ROBOT@SECONDS (e.g. {key}=2@10), got {v!r}"
    out = _read(int, r, message), _read(float, t, message)
    if not sep or not math.isfinite(out[1]) or out[1] < 0:
        raise ValueError(message)
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
            kw[key] = _read(float, v, f"faults: {key} must be a number, got {v!r}")
        elif key in ("kill", "killonly", "late"):
            if key != "late" and "kill" in kw:
                raise ValueError("faults: one kill (kill or killonly) per run")
            kw["late" if key == "late" else "kill"] = _robot_at(key, v)
            if key == "killonly":
                kw["restart"] = False
        elif key == "jump":
            r, sep, shift = v.partition(":")
            message = f"faults: jump takes ROBOT@SECONDS:SHIFT (e.g. jump=1@10:30), got {v!r}"
            kw[key] = (*_read(lambda s: _robot_at("jump", s), r, message), _read(float, shift, message))
            if not sep or not math.isfinite(kw[key][2]):
                raise ValueError(message)
        elif key == "seed":
            kw[key] = _read(int, v, f"faults: seed must be an integer, got {v!r}")
        else:
            raise ValueError(
                f"faults: unknown key {key!r} (loss, delay, reorder, dup, kill, killonly, late, jump, seed)"
            )
    return Faults(**kw)
