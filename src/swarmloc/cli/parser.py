"""The ``swarmloc`` argument parser: the commands' parsers assembled, in the order ``swarmloc --help`` lists them.

Each command's options, help and function live in its own module, ``swarmloc.cli.commands.<command>``."""

from __future__ import annotations

import argparse

from swarmloc import __version__
from swarmloc.cli.commands import (
    compare,
    config,
    consistency,
    data,
    demo,
    evaluate,
    keys,
    node,
    ros,
    router,
    server,
    simulate,
    team,
)
from swarmloc.cli.commands import map as map_

COMMANDS = (demo, evaluate, simulate, config, node, server, router, keys, compare, consistency, map_, ros, team, data)
"""The command modules, each with ``add_parser(sub)`` and ``run(args)``, in the order of ``swarmloc --help``."""


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``swarmloc``: ``--version`` and a subcommand, each bound to its module's ``run``."""
    p = argparse.ArgumentParser(prog="swarmloc", description="Multi-robot cooperative localization on SE(2)/SE(3).")
    p.add_argument("--version", action="version", version=f"swarmloc {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return p
