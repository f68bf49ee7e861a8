"""Association of anonymous robot detections: tags vs nearest vs joint vs anonymous, against density and clutter.

    python benchmarks/association.py                  # docs/association.md: 4/8/16 robots x clutter 0/1/3, 10 seeds
    python benchmarks/association.py --robots 6 --clutter 0,2 --seeds 3 --estimator ci

Each seed's simulated team (``sim:range_bearing``: robots in one 3 m arena, so more robots is a denser crowd;
range-bearing detections at 5 Hz) is run by ``--estimator`` (default ``cekf``) with the same misses
(``--p-detect``) and Poisson clutter per scan (:func:`swarmloc.experiments.association.association_events`):

* ``tags``: identities given, the untagged clutter refused (the reference);
* ``nearest``, ``joint``: identities hidden, chosen by the nodes (:mod:`swarmloc.node.associate`);
* ``anonymous``: identities hidden, PMR + a particle-filter bank per robot hands tagged relative poses to the
  filter (:func:`swarmloc.association.tracker.bank_detections`, ``--handoff``); up to ``--anonymous-max`` robots.

Printed per setting, over the seeds: association accuracy (anonymous detections given their true identity, a false
one refused as clutter counted right; for ``anonymous``, which names no detection, the share of its hand-offs whose
true relative pose is inside the 99.9% gate of the hand-off, :func:`~swarmloc.experiments.association.handoff_accuracy`;
``-`` where there is nothing to score), team position RMSE [m] (pooled),
ANEES per dof (pooled), and the fused / rejected detections summed. Runs in ``--jobs`` worker processes.
"""

from __future__ import annotations

import argparse
import multiprocessing
import platform
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

POLICIES = ("tags", "nearest", "joint", "anonymous")


def one(
    robots: int, clutter: float, seed: int, policy: str, estimator: str, duration: float, p_detect: float,
    handoff: str = "full",
    fresh: int = 0,
):  # fmt: skip
    """One run: ``(sum of squared position errors, of NEES, records, right, wrong, fused, rejected)``."""
    from swarmloc.estimators import make_team, node_options
    from swarmloc.evaluation.metrics import errors
    from swarmloc.experiments.association import association_events, handoff_accuracy
    from swarmloc.experiments.sources import load_source
    from swarmloc.runner import run

    src = load_source("sim:range_bearing", robots=robots, duration=duration, seed=seed)
    # PMR and the banks alone: no lone detection passed on to the nodes' assignment (the table in the docs)
    events, _ = association_events(src.events, policy, sorted(src.initial), src.config.motion.noise(),
                                   clutter=clutter, p_detect=p_detect, max_range=5.0, seed=seed,
                                   bank={"handoff": handoff, "fresh": None if fresh < 0 else fresh,
                                         "lone": False})  # fmt: skip
    opts = node_options(estimator, src.config, src.landmarks, src.t_start)
    if policy in ("nearest", "joint"):
        opts["association"] = policy
    res = run(make_team(estimator, src.initial, **opts), events, src.record_times(), src.truth)
    se = nees = 0.0
    n = 0
    for tr in res.tracks.values():
        e = errors(tr)
        se += float(np.sum(e["pos"] ** 2))
        nees += float(np.sum(e["nees"]))
        n += e["pos"].size
    s = res.stats
    right, wrong = s["association_right"], s["association_wrong"]
    if policy == "anonymous":  # no detection gets an identity: score the hand-offs of named robots against the truth
        right, wrong = handoff_accuracy(events, src.truth)
    return se, nees, n, right, wrong, s["fused"], s["rejected"]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", default="4,8,16", help="team sizes in the same arena, comma-separated")
    p.add_argument("--clutter", default="0,1,3", help="mean false detections per scan, comma-separated")
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--duration", type=float, default=20.0)
    p.add_argument("--p-detect", type=float, default=0.9)
    p.add_argument("--estimator", default="cekf")
    p.add_argument("--anonymous-max", type=int, default=16, help="largest team run with 'anonymous' (its cost)")
    p.add_argument("--policies", default=",".join(POLICIES), help="comma-separated subset of " + ",".join(POLICIES))
    p.add_argument(
        "--fresh",
        type=int,
        default=0,
        help="anonymous: hand off only filters PMR confirmed within this many scans (-1: no condition)",
    )
    p.add_argument("--handoff", default="full", choices=("new", "full"), help="anonymous: the bank's hand-off")
    p.add_argument("--jobs", type=int, default=2)
    a = p.parse_args()
    sizes = [int(r) for r in a.robots.split(",")]
    clutters = [float(c) for c in a.clutter.split(",")]
    policies = [q for q in POLICIES if q in a.policies.split(",")]
    tasks = [
        (n, c, s, pol, a.estimator, a.duration, a.p_detect, a.handoff, a.fresh)
        for n in sizes for c in clutters for pol in policies for s in range(a.seeds)
        if pol != "anonymous" or n <= a.anonymous_max
    ]  # fmt: skip
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs, mp_context=multiprocessing.get_context("spawn")) as ex:
        out = dict(zip(tasks, ex.map(one, *zip(*tasks, strict=True), chunksize=1), strict=True))
    print(f"# {a.estimator}, sim:range_bearing (3 m arena), {a.duration:g} s, seeds 0-{a.seeds - 1}, p_detect "
          f"{a.p_detect}, anonymous hand-off {a.handoff!r} fresh {a.fresh}; {time.perf_counter() - t0:.0f} s wall "
          f"with {a.jobs} jobs; {platform.machine()}, python {platform.python_version()}")  # fmt: skip
    print(
        "| robots | clutter/scan | policy | association accuracy | team pos RMSE [m] | ANEES/dof | fused | rejected |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for n in sizes:
        for c in clutters:
            for pol in policies:
                rs = [out[t] for t in tasks if t[:2] == (n, c) and t[3] == pol]
                if not rs:
                    continue
                se, nees, k, right, wrong, fused, rej = (sum(x) for x in zip(*rs, strict=True))
                acc = f"{right / (right + wrong):.3f}" if right + wrong else "-"
                print(f"| {n} | {c:g} | {pol} | {acc} | {np.sqrt(se / k):.3f} | {nees / k / 3:.2f} | {fused} | "
                      f"{rej} |")  # fmt: skip


if __name__ == "__main__":
    main()
