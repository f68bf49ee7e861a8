"""Fingerprints of every estimator's results, to show that a refactoring changed no result.

Record on the code before and after a change, then compare (recorded beliefs to ``--atol``, default 1e-9, counters
and reasons identical)::

    python tests/_fingerprint.py record before.npz            # on the old code
    python tests/_fingerprint.py record after.npz             # on the new code
    python tests/_fingerprint.py compare before.npz after.npz

What is recorded (each a *case*: the recorded times, means and covariances of every robot, the counters and the
reasons): every planar estimator on ``sim:random``, ``sim:range_bearing`` and ``sim:landmarks`` (3 robots, 20 s);
every SE(3) estimator on ``sim:3d``, ``sim:3d_rbe`` and ``sim:3d_landmarks``; the planar filters on MRCLAM dataset 6
(the first 60 s, with and without landmarks; ``--mrclam DIR``, default ``$SWARMLOC_MRCLAM`` or ``../shared``'s
copy, left out with ``--no-data``); the engine (numpy on ``sim:random``, and
``sim:landmarks`` with dekf; numba on ``sim:landmarks``: the compiled replays and dekf's swarm step); with
``--net``, live teams of node processes (diekf and rdl, 3 robots, 8 s; their network counters depend on timing and
are left out, the filters' own are compared). ``--only SUBSTRING`` records the cases whose name contains it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PLANAR = ("sim:random", "sim:range_bearing", "sim:landmarks")
SPATIAL = ("sim:3d", "sim:3d_rbe", "sim:3d_landmarks")
MRCLAM_ESTIMATORS = ("dr", "expfusion", "dekf", "cekf", "iekf", "ci", "rdl", "irdl", "diekf", "fls", "flsd")
ENGINE_NUMPY = ("expfusion", "ci", "dekf")
ENGINE_COMPILED = ("cekf", "iekf", "rdl", "diekf")
NET_COUNTERS = ("detections", "fused", "gated", "rejected", "unknown", "pending", "odometry")


def _nodes(spec: str, estimator: str, **source: object) -> Callable[[], object]:
    """A case: ``estimator``'s nodes on source ``spec``, recorded as ``swarmloc compare`` records them."""

    def case() -> object:
        from swarmloc.estimators import make_team, node_options
        from swarmloc.experiments.se3 import se3_team, with_truth
        from swarmloc.experiments.sources import load_source
        from swarmloc.runner import run

        src = load_source(spec, **source)  # type: ignore[arg-type]
        if src.noise is not None:
            return run(se3_team(src, estimator), with_truth(src), None, name=estimator)
        opts = node_options(estimator, src.config, src.landmarks, src.t_start, src.sensor)
        return run(make_team(estimator, src.initial, **opts), src.events, src.record_times(), truth=src.truth)

    return case


def _engine(spec: str, estimator: str, backend: str) -> Callable[[], object]:
    def case() -> object:
        from swarmloc.engine.replay import run_engine
        from swarmloc.experiments.sources import load_source

        fixed = {"adaptive": False} if estimator == "diekf" else {}  # the engine's diekf keeps its noise fixed
        return run_engine(load_source(spec, robots=3, duration=20.0, seed=1), estimator, backend=backend, **fixed)

    return case


def _team(estimator: str) -> Callable[[], object]:
    def case() -> object:
        from swarmloc.experiments.team import run_team, team_result

        run = run_team(source="sim:landmarks", robots=3, duration=8.0, seed=1, estimator=estimator, max_wall=300.0)
        from swarmloc.experiments.sources import load_source

        res = team_result(run, load_source("sim:landmarks", robots=3, duration=8.0, seed=1), estimator)
        res.stats = {k: res.stats.get(k, 0) for k in NET_COUNTERS}
        res.reasons.clear()  # the collector's and the network's reasons depend on timing
        return res

    return case


def cases(mrclam: Path | None, net: bool) -> Iterator[tuple[str, Callable[[], object]]]:
    """Every case's name and the function that runs it."""
    from swarmloc.estimators import ESTIMATORS, ESTIMATORS_SE3

    for spec in PLANAR:
        for est in ESTIMATORS:
            yield f"nodes/{spec}/{est}", _nodes(spec, est, robots=3, duration=20.0, seed=1)
    for spec in SPATIAL:
        for est in ESTIMATORS_SE3:
            yield f"nodes/{spec}/{est}", _nodes(spec, est, robots=3, duration=10.0, seed=1)
    if mrclam is not None:
        for landmarks in (True, False):
            for est in MRCLAM_ESTIMATORS:
                spec = f"mrclam:{mrclam / 'MRCLAM_Dataset6'}"
                name = f"nodes/mrclam6{'' if landmarks else '-nolm'}/{est}"
                yield name, _nodes(spec, est, duration=60.0, landmarks=landmarks)
    for est in ENGINE_NUMPY:
        yield f"engine/numpy/sim:random/{est}", _engine("sim:random", est, "numpy")
    yield "engine/numpy/sim:landmarks/dekf", _engine("sim:landmarks", "dekf", "numpy")
    yield "engine/numba/sim:landmarks/dekf", _engine("sim:landmarks", "dekf", "numba")  # the swarm step's kernels
    for est in ENGINE_COMPILED:
        yield f"engine/numba/sim:landmarks/{est}", _engine("sim:landmarks", est, "numba")
    if net:
        for est in ("diekf", "rdl"):
            yield f"team/{est}", _team(est)


def arrays_of(name: str, res: object) -> dict[str, np.ndarray]:
    """A result's arrays under ``<case>|<robot>|<field>``, its counters and reasons as JSON under ``<case>|json``."""
    out: dict[str, np.ndarray] = {}
    for r, tr in sorted(res.tracks.items()):  # type: ignore[attr-defined]
        for f in ("times", "mean", "cov"):
            out[f"{name}|{r}|{f}"] = np.asarray(getattr(tr, f), dtype=float)
    counts = {"stats": dict(sorted(res.stats.items())), "reasons": dict(sorted(res.reasons.items()))}  # type: ignore[attr-defined]
    out[f"{name}|json"] = np.frombuffer(json.dumps(counts, default=int).encode(), dtype=np.uint8)
    return out


def record(out: Path, mrclam: Path | None, net: bool, only: str) -> None:
    data: dict[str, np.ndarray] = {}
    for name, case in cases(mrclam, net):
        if only not in name:
            continue
        t = time.perf_counter()
        data.update(arrays_of(name, case()))
        print(f"{name}: {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    np.savez_compressed(out, **data)
    print(f"{out}: {sum(k.endswith('|json') for k in data)} cases")


def compare(a: Path, b: Path, atol: float) -> int:
    """0 when every case of ``a`` is in ``b`` with equal counters and beliefs within ``atol``; else 1."""
    x, y = np.load(a), np.load(b)
    problems, worst = [], 0.0
    for k in sorted(set(x.files) | set(y.files)):
        if k not in x.files or k not in y.files:
            problems.append(f"{k}: only in {a if k in x.files else b}")
            continue
        u, v = x[k], y[k]
        if k.endswith("|json"):
            if u.tobytes() != v.tobytes():
                problems.append(f"{k}: counters differ:\n  {u.tobytes().decode()}\n  {v.tobytes().decode()}")
            continue
        if u.shape != v.shape:
            problems.append(f"{k}: shape {u.shape} vs {v.shape}")
            continue
        same_nan = np.array_equal(np.isnan(u), np.isnan(v))
        d = float(np.nanmax(np.abs(u - v))) if u.size and not np.isnan(u).all() else 0.0
        worst = max(worst, d)
        if not same_nan or d > atol:
            problems.append(f"{k}: max |difference| {d:.3g}" + ("" if same_nan else " (NaN in different places)"))
    cases_n = sum(k.endswith("|json") for k in x.files)
    print("\n".join(problems) if problems else f"{cases_n} cases equal (largest difference {worst:.3g})")
    return 1 if problems else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out", type=Path)
    r.add_argument("--mrclam", type=Path, default=None)
    r.add_argument("--no-data", action="store_true")
    r.add_argument("--net", action="store_true")
    r.add_argument("--only", default="")
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    c.add_argument("--atol", type=float, default=1e-9)
    args = p.parse_args(argv)
    if args.cmd == "compare":
        return compare(args.a, args.b, args.atol)
    root = args.mrclam or Path(os.environ.get("SWARMLOC_MRCLAM", REPO.parent / "shared" / "data" / "mrclam"))
    record(args.out, None if args.no_data else root, args.net, args.only)
    return 0


if __name__ == "__main__":
    sys.exit(main())
