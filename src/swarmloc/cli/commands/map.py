"""``swarmloc map``: the chapter's map-building experiment (:mod:`swarmloc.experiments.mapping`)."""

from __future__ import annotations

import argparse

from swarmloc.cli.options import real, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``map`` command: its options and help."""
    mp = sub.add_parser("map", help="the chapter's map-building experiment (robots H1, H2): line maps by dead "
                        "reckoning, each robot alone and the cooperative team, their error against the true walls; "
                        "table, figure, GeoJSON/DXF")  # fmt: skip
    mp.add_argument("--seeds", type=int, default=3, help="simulated runs (default 3)")
    mp.add_argument("--first-seed", type=seed, default=0, help="first seed (default 0)")
    mp.add_argument("--estimators", default="expfusion,diekf", help="cooperative estimators (default expfusion,diekf)")
    mp.add_argument("--order", type=int, choices=[1, 2], default=2, help="line propagation order (default 2)")
    mp.add_argument("--sigma", type=real, default=0.01, help="range noise std [m] (default 0.01)")
    mp.add_argument("--D", type=real, default=0.005, help="wheel-speed diffusion [rad^2/s] (default 0.005)")
    mp.add_argument("--out", default=None, help="folder for map.md, map.json, map.png, GeoJSON and DXF maps")
    mp.add_argument("--quiet", action="store_true", help="no progress bar")
    mp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the experiment: the table on stdout; with ``--out``, map.md, map.json, map.png and the first seed's maps
    as GeoJSON (and DXF); 0, or 2 on bad input (one line)."""
    from swarmloc.cli.common import refuse
    from swarmloc.experiments.mapping import figure, map_experiment, markdown
    from swarmloc.experiments.output import write_summary
    from swarmloc.sim.walls import RangeFinder

    ests = tuple(e.strip() for e in args.estimators.split(",") if e.strip())
    try:
        report, first = map_experiment(args.seeds, ests, RangeFinder(sigma=args.sigma), args.order, args.D,
                                       args.first_seed, progress=not args.quiet)  # fmt: skip
    except ValueError as exc:
        return refuse("map", exc)
    text = markdown(report)
    print(text)
    if args.out:
        out = write_summary(args.out, "map", report, text, indent=1, default=str)
        for name, lm in first["maps"].items():
            stem = name.replace(", ", "_").replace(" ", "_")
            lm.save_geojson(out / f"{stem}.geojson")
            lm.save_dxf(out / f"{stem}.dxf")
        figure(out / "map.png", first, ests)
    return 0
