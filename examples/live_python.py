"""Live inputs through the Python API: three robots' nodes (LiveNode, one Zenoh peer each on 127.0.0.1) fed a
simulated team's odometry and detections as they happen (2x real time, 4 s of data), printing beliefs.

    PYTHONPATH=src python examples/live_python.py
"""

import time

import numpy as np

from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.live import LiveNode
from swarmloc.net.transport import free_ports

SPEED = 2.0
src = load_source("sim:random", robots=3, duration=4.0, seed=1)
eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(3)]
nodes = {
    r: LiveNode(
        r,
        src.initial[r],
        team="example",
        roster=src.robots,
        t0=src.t_start,
        config=src.config,
        listen=[eps[i]],
        connect=[e for e in eps if e != eps[i]],
        estimator="rdl",
    )  # fmt: skip
    for i, r in enumerate(src.robots)
}
known = sorted((e.t, i, e) for i, e in enumerate(src.events) if isinstance(e, Odometry | Detection))
w0, shown = time.monotonic(), 0.0
for t, _, e in known:  # each input once it is known: odometry at its interval's end, a detection when made
    time.sleep(max(0.0, w0 + (t - src.t_start) / SPEED - time.monotonic()))
    if isinstance(e, Odometry):
        nodes[e.robot].odometry(e.t0, e.t1, e.v, e.w)
    else:
        nodes[e.observer].detection(e.t, e.z, e.cov, target=e.target)
    if t - shown >= 1.0:
        shown = t
        for r, n in nodes.items():
            b = n.latest
            if b is not None:
                print(f"t={t:4.1f} s  robot {r}: belief at {b.stamp:4.2f} s  x,y,theta = {np.round(n.x, 3)}"
                      f"  sd_xy = {np.sqrt(np.diag(n.P)[:2]).round(3)}")  # fmt: skip
for n in nodes.values():
    n.end()
for r, n in nodes.items():
    rep = n.close(timeout=30)
    b = n.latest
    err = np.linalg.norm(n.x[:2] - src.truth(r, np.array([b.stamp]))[0, :2])
    print(f"robot {r}: {rep.stats['fused']} detections fused; final belief at {b.stamp:.2f} s, error {err:.3f} m; "
          f"inputs refused: {dict(n.feed.reasons) or 'none'}")  # fmt: skip
