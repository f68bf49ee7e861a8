"""``--view``/``--record``/``--linger`` of ``swarmloc node`` and ``swarmloc team``: the live view (Foxglove
WebSocket) and its MCAP recording, checked before the run, opened, and kept up after it."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any


def check_view(args: argparse.Namespace) -> None:
    """Refuse a bad ``--linger``, and ``--view``/``--record`` without the ``view`` extra (one line naming the
    install command), before anything starts."""
    if args.linger is not None and not args.linger >= 0:
        raise ValueError(f"--linger: seconds >= 0 (or none: until Ctrl-C), got {args.linger:g}")
    if args.view is not None or args.record:
        from swarmloc.net.view import require_view

        require_view(args.view is not None, bool(args.record))


def open_view(args: argparse.Namespace, src: Any, detections: Any, name: str, epoch: float | None = None) -> Any:
    """The :class:`~swarmloc.net.view.TeamView` of ``--view``/``--record`` (truth and NEES where the source has
    truth); prints where to connect and where the layout is."""
    from swarmloc.evaluation.metrics import errors
    from swarmloc.net.view import LAYOUT, TeamView

    view = TeamView(port=args.view, mcap=args.record, truth=src.truth, score=errors, detections=detections,
                    roster=src.robots, name=name, epoch=epoch)  # fmt: skip
    if view.url:
        print(f"live view: open {view.url} in Foxglove or Lichtblick (Open connection > Foxglove WebSocket); "
              f"layout: {LAYOUT}", flush=True)  # fmt: skip
    return view


def linger(view: Any, args: argparse.Namespace) -> None:
    """After the run: finish the recording, keep the live view up for ``--linger`` seconds (default: until Ctrl-C
    when stdin and stdout are a terminal, else not at all), then close it. Ctrl-C (or SIGTERM) ends the wait."""
    try:
        view.end_recording()
        seconds = args.linger
        if seconds is None:
            seconds = math.inf if sys.stdin.isatty() and sys.stdout.isatty() else 0.0
        if view.url is None or seconds <= 0:
            return
        until = "until Ctrl-C" if math.isinf(seconds) else f"for {seconds:g} s (Ctrl-C ends it sooner)"
        print(f"live view: the run has ended; still serving {view.url} {until}", flush=True)
        try:
            view.wait(seconds)
            print("live view: closed", flush=True)
        except KeyboardInterrupt:
            print("live view: stopped", flush=True)
    finally:
        view.close()
