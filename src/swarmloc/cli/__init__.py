"""Command line: ``swarmloc demo | reproduce | evaluate | simulate | config | node | server | keys | compare |
consistency | bench | map | ros | team | data``.

Every command writes its results (Markdown, JSON, PNG, TUM) to an output folder and prints a short summary; errors in
the input (a missing dataset file, a malformed line, an unknown estimator, a bad configuration) are reported in
one line (or one line per bad record) with exit status 2, never as a traceback.

Parts: :mod:`.parser` (assembles the commands), :mod:`.commands` (one module per command: its options, help and
function), :mod:`.options` (argument groups several commands share), :mod:`.common` (their shared run-time helpers),
:mod:`.liveview` (the live view of ``node`` and ``team``).
``python -m swarmloc.cli`` runs :func:`main`.
"""

from __future__ import annotations

from swarmloc.cli.parser import build_parser

__all__ = ["build_parser", "main"]


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
