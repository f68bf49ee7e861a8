"""A node's clock: its present, what it accepts, and how a jump of its robot's clock is recognised.

The **present** is the latest stamp of any input the node accepted (never before its start ``t0``). Against it:

* an input stamped more than ``tolerance`` seconds after the present is from the future: it is refused and
  counted (``future``), never taken as the present, so one input stamped 1e9 s cannot stop a node (the tolerance
  is at most the horizon, default equal to it, so an input taken ahead never makes the present's inputs too old);
* an input stamped more than ``horizon`` seconds before the present (or before ``t0``) is too old: refused;
* in between, an input is filed in the history (a late one is replayed).

A robot's own clock can jump (a reboot, a time sync, a log that loops). Refusing such inputs forever would stop
the node, so refused inputs of the node's own robots are first **held**: when ``confirm`` of them in a row (no
accepted input between them) agree with each other (each within ``tolerance`` of the previous one) and all lie
on the same side (all future, or all too old), the robot's clock has jumped: the node resets its history to its
present belief, re-stamped at the new time, and takes the held inputs (:meth:`Node._clock_jump`, logged and
counted ``clock_jumps`` / ``clock_resets``). Any accepted input in between releases the held ones as refused.
Compare ROS robot_localization, which resets its filter when ROS time jumps back.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["DEFAULT_CONFIRM", "DEFAULT_HORIZON", "DEFAULT_TOLERANCE", "Clock"]

DEFAULT_HORIZON = 5.0
"""Default history horizon [s]: how far back out-of-order input is replayed instead of rejected."""
DEFAULT_TOLERANCE = None
"""Default clock tolerance [s]: how far past the node's present an input may be stamped; None: the horizon (it
may not be more: an input taken that far ahead would make the inputs of the present older than the history)."""
DEFAULT_CONFIRM = 3
"""Inputs in a row that confirm a jump of a robot's clock."""

FUTURE, OLD = "future", "old"


class Clock:
    """Start, present, horizon and tolerance of a node, and the inputs held while a clock jump is uncertain."""

    def __init__(self, horizon: float, tolerance: float | None, confirm: int, owner: str = "node") -> None:
        tolerance = horizon if tolerance is None else tolerance
        for name, val in (("horizon", horizon), ("tolerance", tolerance)):
            if not (isinstance(val, int | float) and not isinstance(val, bool) and math.isfinite(val) and val > 0):
                raise ValueError(f"{owner}: '{name}' must be a positive number of seconds, got {val!r}")
        if tolerance > horizon:
            raise ValueError(
                f"{owner}: 'tolerance' ({tolerance:g} s) must not exceed the horizon ({horizon:g} s): an input taken "
                "that far ahead would make the inputs of the present older than the history"
            )
        if not (isinstance(confirm, int) and not isinstance(confirm, bool) and 1 <= confirm <= 100):
            raise ValueError(f"{owner}: 'jump_inputs' must be an integer in [1, 100], got {confirm!r}")
        self.horizon = float(horizon)
        self.tolerance = float(tolerance)
        self.confirm = confirm
        self.t0: float | None = None
        self.present = -math.inf
        self.held: list[tuple[float, str, Any]] = []
        """Inputs held as a possible clock jump: ``(stamp, side, input)``, side ``"future"`` or ``"old"``."""

    def start(self, t0: float) -> None:
        self.t0 = float(t0)
        self.present = max(self.present, self.t0)

    def restart(self, t0: float) -> None:
        """A new start after a jump of the robot's clock: ``t0`` is the present."""
        self.t0 = float(t0)
        self.present = float(t0)

    def accept(self, t: float) -> None:
        """``t`` is the stamp of an accepted input."""
        if t > self.present:
            self.present = t

    def too_old(self, t: float) -> str | None:
        """Why an input stamped ``t`` is too old to be filed, or None."""
        if self.t0 is not None and t < self.t0:
            return f"stamp {t} is before the node's start time {self.t0}"
        if t < self.present - self.horizon:
            return "older than the history horizon"
        return None

    def future(self, t: float) -> str | None:
        """Why an input (or the end ``t`` of an odometry interval) is from the future, or None."""
        if t > self.present + self.tolerance:
            return (
                f"stamp {t:.9g} s is {t - self.present:.3g} s past the node's present {self.present:.9g} s "
                f"(tolerance {self.tolerance:g} s)"
            )
        return None

    def side(self, t: float) -> tuple[str, str] | None:
        """``(side, reason)`` for an input that cannot be filed at ``t`` (``side``: ``"future"`` or ``"old"``)."""
        why = self.future(t)
        if why is not None:
            return FUTURE, why
        why = self.too_old(t)
        if why is not None:
            return OLD, why
        return None

    def hold(self, t: float, side: str, item: Any) -> list[tuple[float, str, Any]]:
        """Hold an input of the node's own robot refused at ``t``; returns the held inputs that this one shows were
        not a clock jump (another side, or too far from it), to be refused now."""
        out: list[tuple[float, str, Any]] = []
        if self.held:
            last_t, last_side, _ = self.held[-1]
            if last_side != side or abs(t - last_t) > self.tolerance:
                out, self.held = self.held, []
        self.held.append((t, side, item))
        return out

    def jumped(self) -> bool:
        """True when the held inputs confirm a jump of the robot's clock: ``confirm`` of them at distinct stamps
        (the detections of one instant are one input)."""
        return len({t for t, _, _ in self.held}) >= self.confirm

    def release(self) -> list[tuple[float, str, Any]]:
        out, self.held = self.held, []
        return out
