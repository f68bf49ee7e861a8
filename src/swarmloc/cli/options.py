"""Argument groups and defaults shared by several commands: a network process's (``--team``, ``--listen`` ...),
authentication (``--key``, ``--roster``), the live view (``--view``, ``--record``, ``--linger``), a node's waits
(``--start-timeout`` ...), a sweep's workers (``--jobs``, ``--cluster``) and a team's source (``--source``,
``--estimator`` ...). Each ``add_*`` adds its options to a command's parser, in the order ``--help`` lists them;
every real-valued option of every command is typed :func:`real` (finite)."""

from __future__ import annotations

import argparse
import math

EST_DEFAULT = "dr,dekf,cekf,iekf,expfusion,ci,rdl,diekf"
"""Estimators ``evaluate`` and ``compare`` run by default: every kind, the recommended ``iekf`` (centralized) and
``diekf`` (distributed) included."""

NET_DEFAULT = "diekf"
"""The estimator ``team`` and ``node`` run by default: the recommended distributed filter."""

ASSOCIATION_CHOICES = ("tags", "nearest", "joint", "anonymous")
ASSOCIATION_HELP = (
    "robot detections' identities: tags (given); nearest, joint (robot ids hidden, chosen from the beliefs by every "
    "estimator; dr fuses no detection); anonymous (ids hidden, PMR + particle-filter bank per robot hands tagged "
    "relative poses to any estimator, a detection no other robot's scan of its instant can register is chosen as "
    "by joint; range-bearing detections)"
)


def real(text: str) -> float:
    """The type of every real-valued option: a finite number (argparse names the option when this refuses ``nan``,
    ``inf`` or a word)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


SEED_MAX = 2**32 - 1
"""Largest seed an option takes (what every seeded generator here accepts, and a range no sweep exhausts)."""


def seed(text: str) -> int:
    """The type of every seed option: an integer in ``[0, SEED_MAX]``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a seed, an integer in [0, {SEED_MAX}], got {text!r}") from None
    if not 0 <= value <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"expected a seed, an integer in [0, {SEED_MAX}], got {text!r}")
    return value


def add_sweep_args(p: argparse.ArgumentParser, jobs: int | None = 2) -> None:
    """Where a sweep's runs go: ``--jobs`` local worker processes (omitted when ``jobs`` is None) or ``--cluster``."""
    if jobs is not None:
        p.add_argument("--jobs", type=int, default=jobs, help=f"worker processes (default {jobs})")
    p.add_argument("--cluster", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster: its scheduler's address (tcp://HOST:8786), instead of local worker "
                        "processes; the same results (needs pip install 'swarmloc[cluster]')")  # fmt: skip


def add_net_args(p: argparse.ArgumentParser) -> None:
    """A network process's team, endpoints, Zenoh configuration, wall-clock limit, logging, run id, launcher."""
    p.add_argument("--team", required=True, help="team name (letters, digits, '-', '_'): part of every key")
    p.add_argument("--listen", default=None, help="this peer's Zenoh endpoints, comma-separated (tcp/HOST:PORT)")
    p.add_argument("--connect", default=None, help="the other peers' endpoints, comma-separated")
    p.add_argument("--zenoh-config", default=None, help="a Zenoh JSON5 configuration file (TLS, access control)")
    p.add_argument("--max-wall", type=real, default=None, help="stop after this many wall-clock seconds")
    p.add_argument("--verbose", action="store_true", help="log the node's state every 2 s")
    p.add_argument("--run-id", default=None, help="this run's id, in every key with the team's name (swarmloc team "
                   "gives each run its own, so that two teams of one name never hear each other)")  # fmt: skip
    p.add_argument("--parent-pid", type=int, default=None,
                   help="stop when this process (the launcher that started this one) is gone")  # fmt: skip


def add_auth_args(p: argparse.ArgumentParser) -> None:
    """``--key``, ``--roster``, ``--no-auth``: who signs and whom it accepts."""
    p.add_argument("--key", default=None, help="this process's private key file (swarmloc keys new)")
    p.add_argument("--roster", default=None, help="the team's roster file: member ids and public keys")
    p.add_argument("--no-auth", action="store_true", help="send unsigned, accept unsigned (a trusted network only)")


def add_view_args(p: argparse.ArgumentParser, what: str) -> None:
    """``--view``, ``--record``, ``--linger``; ``what``: whose view, in the help ("of the team")."""
    p.add_argument("--view", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help=f"live view {what} for Foxglove or Lichtblick (Foxglove WebSocket) on ws://127.0.0.1:PORT "
                   "(default 8765; 0: a free port)")  # fmt: skip
    p.add_argument("--record", default=None, metavar="FILE.mcap",
                   help="record the view as MCAP of ROS 2 messages (Foxglove, Lichtblick, ros2 bag play)")  # fmt: skip
    p.add_argument("--linger", type=real, nargs="?", const=math.inf, default=None, metavar="SECONDS",
                   help="keep the live view up after the run ends: SECONDS, or until Ctrl-C without a number; 0: "
                   "stop with the run (default: until Ctrl-C when run from a terminal, else 0)")  # fmt: skip


def add_timeout_args(p: argparse.ArgumentParser) -> None:
    """A node's waits [s] (:data:`swarmloc.net.timeouts.TIMEOUTS`) and ``--answer-retries``."""
    from swarmloc.net.timeouts import ANSWER_RETRIES, TIMEOUTS

    for name, (default, meaning) in TIMEOUTS.items():
        p.add_argument(
            f"--{name.replace('_', '-')}", type=real, default=default, help=f"{meaning} (default {default:g})"
        )
    p.add_argument("--answer-retries", type=int, default=ANSWER_RETRIES,
                   help="how many more times a node asks a query that went unanswered, while its robot is alive "
                        f"(default {ANSWER_RETRIES}); more while within the lost timeout of the first ask")  # fmt: skip


def add_source_args(p: argparse.ArgumentParser, default: str | None) -> None:
    """A team's source and how it is run; ``default``: the ``--source`` default (None: required)."""
    p.add_argument("--source", default=default, required=default is None,
                   help="sim:SCENARIO (random, range_bearing), mrclam:PATH or events:PATH; swarmloc node also "
                        "zenoh:SPEC or ros2:SPEC (inputs live, the team from SPEC)")  # fmt: skip
    p.add_argument("--estimator", default=NET_DEFAULT,
                   help=f"a distributed estimator (diekf, expfusion, dekf, ci, rdl, irdl) or a centralized one the "
                        f"belief server hosts (cekf, iekf, fej); default {NET_DEFAULT}, the recommended distributed "
                        "filter")  # fmt: skip
    p.add_argument("--config", default=None, help="TOML file of model and filter settings")
    p.add_argument("--robots", type=int, default=3, help="sim: team size (default 3)")
    p.add_argument("--duration", type=real, default=None, help="seconds of the source (sim default 30)")
    p.add_argument("--seed", type=seed, default=0, help="sim: seed")
    p.add_argument("--speed", type=real, default=0.0, help="x real time; 0: as fast as lockstep allows")
    p.add_argument("--lag", type=real, default=0.5, help="lockstep slack in seconds of data time")
    p.add_argument("--faults", default=None, help="loss=P,delay=S,reorder=P,dup=P,kill=R@T,late=R@T,seed=N")
    p.add_argument("--ros-domain", type=int, default=None, help="also publish ROS 2 poses (rmw_zenoh, this domain)")
    p.add_argument("--association", choices=ASSOCIATION_CHOICES, default=None,
                   help=ASSOCIATION_HELP + " (default: the configuration's [filter] association)")  # fmt: skip
