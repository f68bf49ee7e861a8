"""Command line of the research studies: ``swarmloc-studies reproduce | bench``.

One module per command, named as the command (``swarmloc-studies bench`` -> :mod:`.bench`): its
``add_parser(sub)`` (the options and their help) and its ``run(args)`` (the exit status), as in
:mod:`swarmloc.cli.commands`. The ``swarmloc-studies`` program and ``python -m swarmloc_studies.cli`` run
:func:`console`.
"""

from __future__ import annotations

import argparse

from swarmloc import __version__
from swarmloc.cli import exit_with
from swarmloc_studies.cli import bench, reproduce

__all__ = ["COMMANDS", "build_parser", "console", "main"]

COMMANDS = (reproduce, bench)
"""The command modules, each with ``add_parser(sub)`` and ``run(args)``, in the order of ``--help``."""


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``swarmloc-studies``: ``--version`` and a subcommand, each bound to its module's ``run``."""
    p = argparse.ArgumentParser(prog="swarmloc-studies", description="swarmloc's research studies: the thesis "
                                "reproduction and the benchmarks.")  # fmt: skip
    p.add_argument("--version", action="version", version=f"swarmloc-studies (swarmloc {__version__})")
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` (default: the process's arguments) and run the command; its exit status."""
    args = build_parser().parse_args(argv)
    return int(args.func(args))


def console() -> None:
    """The ``swarmloc-studies`` program: :func:`main`, then exit with its status (:func:`swarmloc.cli.exit_with`)."""
    exit_with(main())
