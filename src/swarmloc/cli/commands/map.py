"""``swarmloc map``: the chapter's map-building experiment (:mod:`swarmloc.experiments.mapping`)."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``map`` command: its options and help."""
    mp = sub.add_parser("map", help="the chapter's map-building experiment (robots H1, H2): line maps by dead "
                        "reckoning, each robot alone and the cooperative team, their error against the true walls; "
                        "table, figure, GeoJSON/DXF")  # fmt: skip
    mp.add_argument("--seeds", type=int, default=3, help="simulated runs (default 3)")
    mp.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    mp.add_argument("--estimators", default="expfusion,diekf", help="cooperative estimators (default expfusion,diekf)")
    mp.add_argument("--order", type=int, choices=[1, 2], default=2, help="line propagation order (default 2)")
    mp.add_argument("--sigma", type=float, default=0.01, help="range noise std [m] (default 0.01)")
    mp.add_argument("--D", type=float, default=0.005, help="wheel-speed diffusion [rad^2/s] (default 0.005)")
    mp.add_argument("--out", default=None, help="folder for map.md, map.json, map.png, GeoJSON and DXF maps")
    mp.add_argument("--quiet", action="store_true", help="no progress bar")
    mp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the experiment; its exit status."""
    from swarmloc.experiments.mapping import run_command

    return run_command(args)
