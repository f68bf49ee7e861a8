"""Run-time helpers the commands share: the one-line refusal of a bad input, the configuration file, a team's source,
comma-separated ids and endpoints, a network process's logging, keys, launcher and waits."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def refuse(command: str, message: object) -> int:
    """An error in the input of ``swarmloc <command>`` said in one line on stderr; the command's exit status 2."""
    print(f"swarmloc {command}: {message}", file=sys.stderr)
    return 2


def run_config(args: argparse.Namespace):  # noqa: ANN202
    """The configuration of ``--config`` (a TOML file), else the defaults."""
    from swarmloc.config import DEFAULTS, load_config

    return load_config(args.config) if args.config else DEFAULTS


def team_source(args: argparse.Namespace, spec: str, robots: int):  # noqa: ANN201
    """The team's source ``spec`` (``robots`` robots, ``--duration``, ``--seed``, ``--config`` when given) with its
    robot detections' identities as ``--association`` says
    (:func:`~swarmloc.experiments.association.with_association`)."""
    from swarmloc.experiments.association import with_association
    from swarmloc.experiments.sources import load_source

    config = run_config(args) if args.config else None
    src = load_source(spec, robots=robots, duration=args.duration, seed=args.seed, config=config)
    return with_association(src, args.association)


def ids(text: str | None) -> list[int] | None:
    """``"1,2,3"`` -> ``[1, 2, 3]``; ``"none"`` -> ``[]``; None -> None."""
    if text is None:
        return None
    if text.strip().lower() == "none":
        return []
    return [int(x) for x in text.split(",") if x.strip()]


def endpoints(text: str | None) -> list[str]:
    """``"tcp/a:1, tcp/b:2"`` -> ``["tcp/a:1", "tcp/b:2"]``; None -> ``[]``."""
    return [x.strip() for x in (text or "").split(",") if x.strip()]


def net_logging(verbose: bool) -> None:
    """Log to stderr: INFO with ``--verbose``, else WARNING."""
    import logging

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")  # fmt: skip


def load_auth(args: argparse.Namespace, member: int):  # noqa: ANN202
    """The process's :class:`~swarmloc.net.auth.Auth` from ``--key`` and ``--roster``; None with ``--no-auth``."""
    from swarmloc.net.auth import Auth

    if args.no_auth:
        if args.key or args.roster:
            raise ValueError("--no-auth takes neither --key nor --roster")
        print("warning: --no-auth: any process on the network can speak in any member's name (and write a "
              "zenoh: source's live inputs)", file=sys.stderr)  # fmt: skip
        return None
    if not (args.key and args.roster):
        raise ValueError("give this process's --key FILE and the team's --roster FILE (make them with "
                         "'swarmloc keys'), or --no-auth on a trusted network")  # fmt: skip
    return Auth.load(args.key, args.roster, member)


def die_with_launcher(args: argparse.Namespace) -> None:
    """With ``--parent-pid``: end this process when its launcher is gone."""
    if args.parent_pid is not None:  # first thing: a launcher killed meanwhile must not leave this process running
        from swarmloc.net.lifeline import die_with_parent

        die_with_parent(args.parent_pid)


def timeouts(args: argparse.Namespace) -> dict[str, Any]:
    """The node's waits [s] and its ``answer_retries`` (a count) from the command line."""
    from swarmloc.net.timeouts import TIMEOUTS

    return {**{name: getattr(args, name) for name in TIMEOUTS}, "answer_retries": args.answer_retries}
