"""Command line: ``swarmloc demo | evaluate | simulate | config | node | server | router | keys | compare | consistency
| map | ros | team | data`` (the research studies' commands are ``swarmloc-studies``, a package of its own).

Every command writes its results (Markdown, JSON, PNG, TUM) to an output folder and prints a short summary; errors in
the input (a missing dataset file, a malformed line, an unknown estimator, a bad configuration) are reported in
one line (or one line per bad record) with exit status 2, never as a traceback.

Parts: :mod:`.parser` (assembles the commands), :mod:`.commands` (one module per command: its options, help and
function), :mod:`.options` (argument groups several commands share), :mod:`.common` (their shared run-time helpers),
:mod:`.liveview` (the live view of ``node`` and ``team``).
The ``swarmloc`` program and ``python -m swarmloc.cli`` run :func:`console`.
"""

from __future__ import annotations

from typing import NoReturn

from swarmloc.cli.parser import build_parser

__all__ = ["build_parser", "console", "exit_with", "main"]


def main(argv: list[str] | None = None) -> int:
    import sys

    argv = list(sys.argv[1:] if argv is None else argv)
    ros = None
    if "--ros-args" in argv:  # ROS's own arguments (swarmloc ros), read as rcl reads them
        from swarmloc.ros.args import RosArgsError, parse_ros_args

        try:
            ros, argv = parse_ros_args(argv)
        except RosArgsError as exc:
            print(f"swarmloc: {exc}", file=sys.stderr)
            return 2
    args = build_parser().parse_args(argv)
    args.ros_args = ros
    return int(args.func(args))


def console() -> None:
    """The ``swarmloc`` program: :func:`main`, then :func:`exit_with` its status."""
    exit_with(main())


def exit_with(rc: int) -> NoReturn:
    """End the process with status ``rc`` (the ``swarmloc`` programs' last step).

    A process that imported Zenoh ends with ``os._exit`` once its logs and output are flushed, without finalizing
    the interpreter: Zenoh's runtime threads outlive the sessions a command closed and drop the callbacks Python gave
    them on their own schedule; one that needs the interpreter while it finalizes is ended by CPython (3.11-3.13)
    with a forced unwind through native frames, which aborts the whole process ("FATAL: exception not rethrown",
    SIGABRT) after the command has done its work. Every command closes its files and sessions before it returns."""
    import sys

    if "zenoh" in sys.modules:
        import logging
        import os

        logging.shutdown()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # a closed pipe: nothing more can be said
                pass
        os._exit(rc)
    raise SystemExit(rc)
