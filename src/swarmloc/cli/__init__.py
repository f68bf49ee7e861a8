"""Command line: ``swarmloc demo | reproduce | evaluate | simulate | config | compare | node | server | team | keys
| data``.

Every command writes its results (Markdown, JSON, PNG, TUM) to an output folder and prints a short summary; errors in
the input (a missing dataset file, a malformed line, an unknown estimator, a bad configuration) are reported in
one line (or one line per bad record) with exit status 2, never as a traceback.

Parts: :mod:`.parser` (the commands, their options and help), :mod:`.offline` (the commands that run in one process),
:mod:`.network` (a robot's process, the belief server, a team, keys), :mod:`.data` (downloads of public data).
``python -m swarmloc.cli`` runs :func:`main`.
"""

from __future__ import annotations

from swarmloc.cli.parser import build_parser

__all__ = ["build_parser", "main"]


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))
