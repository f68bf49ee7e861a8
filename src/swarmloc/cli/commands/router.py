"""``swarmloc router``: a Zenoh router for teams whose robots are on several machines (instead of ``zenohd``)."""

from __future__ import annotations

import argparse

from swarmloc.cli.common import endpoints, net_logging, refuse
from swarmloc.cli.options import real


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``router`` command: its options and help."""
    r = sub.add_parser("router", help="run a Zenoh router: robots on several machines join it as clients, routers "
                       "mesh with each other (instead of zenohd)")  # fmt: skip
    r.add_argument("--listen", default="tcp/0.0.0.0:7447",
                   help="endpoints to listen on, comma-separated (default tcp/0.0.0.0:7447, Zenoh's port)")  # fmt: skip
    r.add_argument("--connect", default=None, help="the other routers' endpoints, comma-separated (a mesh)")
    r.add_argument("--zenoh-config", default=None, help="a Zenoh JSON5 configuration file (TLS, access control)")
    r.add_argument("--max-wall", type=real, default=None, help="stop after this many wall-clock seconds")
    r.add_argument("--verbose", action="store_true", help="log at INFO")
    r.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Relay until Ctrl-C, SIGTERM or ``--max-wall``; 0, or 2 when the router cannot start."""
    import math
    import signal
    import threading

    from swarmloc.net.timeouts import wait_event
    from swarmloc.net.transport import TransportError, open_session

    net_logging(args.verbose)
    if args.max_wall is not None and not (math.isfinite(args.max_wall) and args.max_wall > 0):
        return refuse("router", f"--max-wall must be a positive number of seconds, got {args.max_wall}")
    listen = endpoints(args.listen)
    try:
        session = open_session(listen, endpoints(args.connect), args.zenoh_config, mode="router")
    except TransportError as exc:  # an endpoint taken or malformed, a bad configuration file
        return refuse("router", exc)
    except OSError as exc:
        return refuse("router", f"cannot start ({exc})")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print(f"swarmloc router: relaying on {', '.join(listen) or 'the configuration file endpoints'}", flush=True)
    try:
        wait_event(stop, args.max_wall)  # in slices: Ctrl-C and SIGTERM are taken whichever thread receives them
    except KeyboardInterrupt:
        pass
    finally:
        session.close()
    return 0
