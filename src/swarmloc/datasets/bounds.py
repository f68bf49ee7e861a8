"""Bounds on what is read from outside (event files, ground truth), and bad lines kept in bounded memory.

The bounds are physically generous: a value beyond them is a typing or unit error, not a measurement, and letting
it through would overflow the filters (``1e308`` m squared is ``inf``) or the record grid. Units: metres,
radians, seconds.

* ``MAX_STAMP`` = 1e10 s: any time stamp or interval end, in magnitude (Unix epoch time reaches it in 2286);
* ``MAX_POSITION`` = 1e6 m: ``|x|``, ``|y|`` of any pose or point (initial belief, absolute fix, landmark,
  relative pose) and any range (1000 km);
* ``MAX_ANGLE`` = 1e4 rad: a heading in magnitude (unwrapped headings are accepted; beyond that, float64 holds an
  angle to worse than 2e-12 rad);
* ``MAX_SPEED`` = 1e3 m/s and ``MAX_YAW_RATE`` = 1e3 rad/s: odometry ``|v|`` and ``|w|``;
* noise standard deviations in ``[MIN_STD, MAX_STD]`` = ``[1e-12, 1e6]`` (m or rad; a covariance's diagonal in
  their squares): below, the variance underflows the precision of a float64 filter; above, it says nothing;
* ``MAX_ID`` = 2**31 - 1: robot and landmark ids;
* ``MAX_LINE_CHARS`` = 65536: one line of a text file (a record is under 1000 characters).

:class:`BadLines` collects one file's bad lines in bounded memory: the first ``MAX_LISTED`` messages by line
number in full, the next ``MAX_NUMBERS`` line numbers, and the count of all.
"""

from __future__ import annotations

import heapq

__all__ = [
    "MAX_ANGLE",
    "MAX_ID",
    "MAX_LINE_CHARS",
    "MAX_LISTED",
    "MAX_NUMBERS",
    "MAX_POSITION",
    "MAX_SPEED",
    "MAX_STAMP",
    "MAX_STD",
    "MAX_YAW_RATE",
    "MIN_STD",
    "BadLines",
    "shorten",
]

MAX_STAMP = 1e10
MAX_POSITION = 1e6
MAX_ANGLE = 1e4
MAX_SPEED = 1e3
MAX_YAW_RATE = 1e3
MIN_STD = 1e-12
MAX_STD = 1e6
MAX_ID = 2**31 - 1
MAX_LINE_CHARS = 65536

MAX_LISTED = 20
"""Bad-line messages kept in full."""
MAX_NUMBERS = 50
"""Line numbers kept of the bad lines beyond the first ``MAX_LISTED``."""


def shorten(text: str, n: int = 80) -> str:
    """``text`` cut to ``n`` characters (with ``...``)."""
    return text if len(text) <= n else text[: n - 3] + "..."


class BadLines:
    """The bad lines of one file, in memory bounded whatever their number.

    ``add(line, problem)`` in any order; :meth:`messages` gives the ``MAX_LISTED`` lowest-numbered as
    ``"<label> line <n>: <problem>"``, then one line saying how many more and which (the ``MAX_NUMBERS`` next line
    numbers). ``n`` counts them all.
    """

    def __init__(self, label: str) -> None:
        self.label = label
        self.n = 0
        self._listed: list[tuple[int, int, str]] = []  # max-heap on (line, order): (-line, -order, message)
        self._more: list[int] = []  # max-heap of the next line numbers: -line
        self._order = 0

    def add(self, line: int, problem: str) -> None:
        """Count one bad line; keep its message if it is among the first ``MAX_LISTED`` by line number."""
        self.n += 1
        self._order += 1
        heapq.heappush(self._listed, (-line, -self._order, f"{self.label} line {line}: {problem}"))
        if len(self._listed) > MAX_LISTED:
            dropped = -heapq.heappop(self._listed)[0]
            heapq.heappush(self._more, -dropped)
            if len(self._more) > MAX_NUMBERS:
                heapq.heappop(self._more)

    def messages(self) -> list[str]:
        """The kept messages by line number, and a last line for the others when there are more."""
        out = [m for _, _, m in sorted(self._listed, key=lambda x: (-x[0], -x[1]))]
        rest = self.n - len(out)
        if rest:
            lines = sorted(-x for x in self._more)
            more = ", ".join(str(k) for k in lines) + (", ..." if rest > len(lines) else "")
            out.append(f"... and {rest} more (lines {more})")
        return out

    def summary(self, hint: str = "") -> str:
        """A multi-line message: how many bad lines in all (and ``hint``), then :meth:`messages`, indented."""
        head = f"{self.label}: {self.n} bad line{'s' if self.n != 1 else ''}{f' ({hint})' if hint else ''}:"
        return "\n".join([head, *(f"  {m}" for m in self.messages())])
