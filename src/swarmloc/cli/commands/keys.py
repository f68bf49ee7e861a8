"""``swarmloc keys new | roster | team``: Ed25519 key pairs and the team's roster (authenticated senders)."""

from __future__ import annotations

import argparse

from swarmloc.cli.common import ids, refuse
from swarmloc.cli.options import real


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``keys`` command: its options and help."""
    k = sub.add_parser("keys", help="make Ed25519 key pairs and the team's roster (authenticated senders)")
    ks = k.add_subparsers(dest="keys_command", required=True)
    n = ks.add_parser("new", help="a key pair: FILE (private, mode 0600) and FILE.pub (public, base64)")
    n.add_argument("file")
    r = ks.add_parser("roster", help="a roster from the members' public keys: 0=robot0.key.pub server=... ")
    r.add_argument("members", nargs="+", help="MEMBER=KEY: a robot id, 'server' or 'collector' = a .pub file, "
                   "a private key file or base64")  # fmt: skip
    r.add_argument("--out", required=True, help="the roster file to write")
    t = ks.add_parser("team", help="every key of a team and its roster in one folder (for one trusted machine)")
    t.add_argument("--robots", required=True, help="robot ids, comma-separated")
    t.add_argument("--out", required=True, help="folder for robot<id>.key, server.key, collector.key, roster.json")
    for p in (r, t):
        p.add_argument("--max-age", type=real, default=30.0, help="seconds a signed stamp may be old (default 30)")
    k.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write a key pair, a roster or a team's keys; 0, or 2 on bad input."""
    import base64

    from swarmloc.net import auth

    try:
        if args.keys_command == "new":
            public = auth.new_key(args.file)
            b64 = base64.b64encode(public).decode()
            print(f"private key {args.file} (mode 0600); public key {args.file}.pub: {b64}")
        elif args.keys_command == "roster":
            members = dict(m.split("=", 1) for m in args.members if "=" in m)
            if len(members) != len(args.members):
                raise ValueError("members are MEMBER=KEY: 0=robot0.key.pub, server=server.key.pub ...")
            keys = {auth.member_id(k.strip()): auth.public_key(v) for k, v in members.items()}
            r = auth.Roster(keys, args.max_age)
            r.save(args.out)
            print(f"roster {args.out}: robots {r.robots}" + ", server" * (-1 in keys) + ", collector" * (-2 in keys))
        else:
            roster, files = auth.make_team_keys(args.out, ids(args.robots) or [], args.max_age)
            print(f"keys of robots {args.robots}, the server and the collector in {args.out}/; roster {roster}")
    except (ValueError, OSError) as exc:
        return refuse("keys", exc)
    return 0
