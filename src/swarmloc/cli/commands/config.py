"""``swarmloc config``: print the default configuration, or check a TOML file."""

from __future__ import annotations

import argparse

from swarmloc.cli.common import refuse


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``config`` command: its options and help."""
    c = sub.add_parser("config", help="print the default configuration, or check a TOML file")
    c.add_argument("--defaults", action="store_true", help="print every default as TOML")
    c.add_argument("--check", metavar="FILE", help="read FILE and print the full configuration it gives")
    c.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print every default (``--defaults``) or the configuration a file gives (``--check``); 0, or 2."""
    from swarmloc.config import DEFAULTS, ConfigError, load_config

    if args.check:
        try:
            cfg = load_config(args.check)
        except ConfigError as exc:
            return refuse("config", exc)
        print(cfg.to_toml(), end="")
        return 0
    if args.defaults:
        print(DEFAULTS.to_toml(), end="")
        return 0
    return refuse("config", "say --defaults (print every default) or --check FILE")
