"""Prototype: ``diekf`` clusters that re-form as the robots move, against fixed clusters and the exact filter, as one
centralized replay of the clusters' joint states (world-frame errors, as the nodes; lazy odometry, in stamp order).

    python benchmarks/diekf_reform.py --robots 10,20,50 --duration 30 --seeds 4 --cluster 5,10 --period 0,1

A cluster's joint covariance is the nodes' replicas of that cluster together. A detection inside a cluster is the
exact update; of a robot outside it, the one-sided covariance-intersection update of ``TeamProtocol.outsider``. Every
``period`` s the team is cut again (``--how``); a new cluster made of pieces of ``m`` old clusters starts from the
covariance-intersection bound of the stacked pieces, ``blockdiag(P_1 / w_1, ..., P_m / w_m)``, ``sum w = 1``
(Julier & Uhlmann 1997; any such weights bound every correlation between the pieces), whose correlations inside a
piece are the old cluster's exact ones; a robot that leaves is marginalized out (``--power``: the weights).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.stats import chi2
from swarm_scene import ARENAS, arena_side, hilbert_index, scene

from swarmloc.datasets.source import Source
from swarmloc.estimators import node_options
from swarmloc.estimators.cluster_reform import Schedule, id_cut, seen_schedule, stacked_bound
from swarmloc.estimators.world_form import WorldForm, robot_pair, world_step
from swarmloc.events import Detection, Odometry
from swarmloc.kernels import invariant as I
from swarmloc.kernels.ci import joint_weight
from swarmloc.lie import SE2

FORM = WorldForm()


class Clustered:
    """The clusters' joint states: poses ``x (n, 3)``, each robot's cluster and place, each cluster's covariance."""

    def __init__(self, src: Source, noise: Any, gate: float, groups: list[list[int]]) -> None:
        n = len(src.robots)
        self.noise, self.thr = noise, chi2.ppf(gate, 3)
        self.x = np.zeros((n, 3))
        P0 = np.zeros((n, 3, 3))
        for r in src.robots:
            self.x[r], P0[r] = FORM.initial(src.initial[r].mean, src.initial[r].cov)
        self.t = np.zeros(n)
        self.cmd = np.zeros((n, 2))
        self.groups: list[list[int]] = []
        self.P: list[np.ndarray] = []
        self.where = np.zeros((n, 2), dtype=int)
        for g in groups:
            self._add(g, np.zeros((3 * len(g), 3 * len(g))))
            for k, r in enumerate(g):
                self.P[-1][3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = P0[r]
        self.fused = self.gated = self.moved = 0
        self.mates = 0
        """Cluster mates of the observer summed over the detections (the broadcast's receivers)."""

    def _add(self, g: list[int], P: np.ndarray) -> None:
        for k, r in enumerate(g):
            self.where[r] = (len(self.groups), k)
        self.groups.append(list(g))
        self.P.append(P)

    def block(self, r: int) -> np.ndarray:
        c, k = self.where[r]
        return self.P[c][3 * k : 3 * k + 3, 3 * k : 3 * k + 3]

    def predicted(self, r: int, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Robot ``r``'s pose and covariance predicted to ``t`` (a copy; the state is not changed)."""
        dt = t - self.t[r]
        if dt <= 0:
            return self.x[r].copy(), self.block(r).copy()
        x0, y0, th, Pr = world_step(*self.x[r].tolist(), self.block(r), *self.cmd[r], dt, self.noise)
        return np.array([x0, y0, th]), Pr

    def advance(self, r: int, t: float) -> None:
        """Robot ``r`` predicted to ``t`` where the nodes predict it: its odometry, its detections, an update of the
        cluster that detected it, a re-forming (a prediction split in two differs in the 7th digit)."""
        if t <= self.t[r]:
            return
        c, k = self.where[r]
        self.x[r], self.P[c][3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = self.predicted(r, t)
        self.t[r] = t

    def odometry(self, e: Odometry) -> None:
        self.advance(e.robot, e.t0)
        self.cmd[e.robot] = (e.v, e.w)

    def detection(self, d: Detection) -> None:
        i, j = d.observer, d.target
        self.mates += len(self.groups[self.where[i][0]]) - 1
        self.advance(i, d.t)
        ci, ki = self.where[i]
        cj, kj = self.where[j]
        xj, Pjj = self.predicted(j, d.t)  # the target's answer (predicted only if its cluster's update is applied)
        lin = robot_pair(d, self.x[i], xj)
        if lin is None:
            return
        r, Hi, Hj, R = lin
        kept = (self.x[j].copy(), self.P[cj].copy(), self.t[j])
        if ci == cj:
            self.advance(j, d.t)
        P = self.P[ci]
        H = np.zeros((len(r), P.shape[0]))
        H[:, 3 * ki : 3 * ki + 3] = Hi
        if ci == cj:
            H[:, 3 * kj : 3 * kj + 3] = Hj
            Pw, Rw = P, R
        else:  # the outsider's belief only: covariance intersection, one-sided
            A, B = Hi @ self.block(i) @ Hi.T, Hj @ Pjj @ Hj.T
            w = joint_weight(A, B, R, P.shape[0])
            Pw, Rw = P / w, R + B / (1.0 - w)
        PH = Pw @ H.T
        S = H @ PH + Rw
        Sinv = np.linalg.inv(S)
        if r @ Sinv @ r > self.thr:
            self.gated += 1
            self.x[j], self.P[cj], self.t[j] = kept
            return
        G = PH @ Sinv
        delta = G @ r
        Pn = Pw - G @ PH.T
        self.P[ci] = 0.5 * (Pn + Pn.T)
        for k, m in enumerate(self.groups[ci]):
            self.x[m] = I.left_correct(self.x[m], delta[3 * k : 3 * k + 3])
        self.fused += 1

    def reform(self, groups: Sequence[Sequence[int]], power: float = 1.0, t: float | None = None) -> None:
        """The team cut into ``groups``: each new cluster from the CI bound of its pieces (module docstring;
        :func:`~swarmloc.estimators.cluster_reform.stacked_bound`, the nodes' own), piece ``k`` of ``s_k`` robots
        weighted ``w_k = s_k^power / sum s^power`` (1: the bound's log det minimized). ``t``: every robot predicted
        to it first (each node predicts its own robot to the re-forming's stamp)."""
        if t is not None:
            for r in range(len(self.x)):
                self.advance(r, t)
        oldP, where = self.P, self.where.copy()
        self.groups, self.P = [], []
        for g in groups:
            old = {r: int(where[r][0]) for r in g}

            def block(a: int, b: int) -> np.ndarray:
                (ca, ka), kb = where[a], where[b][1]
                return oldP[ca][3 * ka : 3 * ka + 3, 3 * kb : 3 * kb + 3]

            B = stacked_bound(g, old, block, 3, power)
            self._add(list(g), B.transpose(0, 2, 1, 3).reshape(3 * len(g), 3 * len(g)))
            if len(set(old.values())) > 1:
                self.moved += len(g)

    def belief(self, r: int) -> tuple[np.ndarray, np.ndarray]:
        return self.x[r].copy(), self.block(r).copy()


def hilbert_groups(f: Clustered, K: int, side: float) -> list[list[int]]:
    """``"hilbert"``: the team cut again into clusters of ``K`` consecutive robots along a Hilbert curve through the
    estimated positions (the grouped arena's cut, redone)."""
    xy = np.clip(f.x[:, :2], 0.0, side)
    order = sorted(range(len(xy)), key=lambda r: hilbert_index(xy[r, 0], xy[r, 1], side))
    return [order[a : a + K] for a in range(0, len(order), K)]


def replay(src: Source, K: int, period: float = 0.0, how: str = "seen", margin: float = 2.0,
           power: float = 1.0) -> dict[str, Any]:  # fmt: skip
    """One run of clusters of ``K`` (``K >= n``: the exact filter) re-formed every ``period`` s (0: never) by ``how``
    (``"seen"``: :func:`~swarmloc.estimators.cluster_reform.seen_schedule` with ``margin``, the nodes' schedule;
    ``"hilbert"``: :func:`hilbert_groups`; ``power``: the pieces' weights, :meth:`Clustered.reform`): RMSE [m] and
    ANEES/dof
    over every robot and record time, detections fused and gated, robots moved, the observer's cluster mates per
    detection (the receivers of its broadcast), the largest cluster, the final clusters, and ``beliefs``: per robot
    ``(t, x, P)`` at every record time (world-frame covariance, as the nodes')."""
    opts = node_options("diekf", src.config, src.landmarks)
    n = len(src.robots)
    side = arena_side(n) if n > 3 else 1.0
    f = Clustered(src, opts["noise"], opts["gate"], [list(g) for g in id_cut(src.robots, K)])
    sched = seen_schedule(src.events, src.robots, K, period, margin) if period > 0 else Schedule((), ((),))
    events = sorted(src.events, key=lambda e: e.stamp)
    errs, nees = [], []
    beliefs: dict[int, list[tuple[float, np.ndarray, np.ndarray]]] = {r: [] for r in src.robots}
    q, b = 0, 0
    for t in [*src.record_times(), math.inf]:
        while q < len(events) and events[q].stamp <= t:
            e = events[q]
            while b < len(sched.times) and e.stamp >= sched.times[b]:
                f.reform(hilbert_groups(f, K, side) if how == "hilbert" else sched.cuts[b + 1], power, sched.times[b])
                b += 1
            if isinstance(e, Odometry):
                f.odometry(e)
            else:
                f.detection(e)
            q += 1
        if t == math.inf:
            break
        for r in src.robots:
            truth = src.truth(r, np.array([t]))[0]
            x, P = f.predicted(r, t)
            beliefs[r].append((t, x, P))
            errs.append(np.hypot(*(x[:2] - truth[:2])))
            xi = SE2.log(SE2.from_xytheta(truth) @ SE2.inverse(SE2.from_xytheta(x)))  # world-frame error
            nees.append(xi @ np.linalg.solve(P, xi))
    return {"rmse": float(np.sqrt(np.mean(np.square(errs)))), "anees": float(np.mean(nees) / 3), "fused": f.fused,
            "gated": f.gated, "moved": f.moved, "mates": f.mates / max(f.fused + f.gated, 1),
            "largest": max(len(g) for g in f.groups), "groups": f.groups, "beliefs": beliefs}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", default="10,20,50")
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--seeds", type=int, default=4, help="this many seeds from --seed, every row their mean")
    ap.add_argument("--cluster", default="10")
    ap.add_argument("--period", default="0,1", help="re-forming periods [s] (0: fixed clusters)")
    ap.add_argument("--how", choices=("seen", "hilbert"), default="seen")
    ap.add_argument("--margin", type=float, default=2.0, help='"seen": how many times more often')
    ap.add_argument("--power", type=float, default=1.0, help="a piece's CI weight: its size to this power")
    ap.add_argument("--arena", choices=ARENAS, default="grouped")
    a = ap.parse_args()
    seeds = list(range(a.seed, a.seed + a.seeds))
    print(
        f"sim:random ({a.arena} arena), seeds {seeds[0]}-{seeds[-1]}, {a.duration:g} s, re-formed by {a.how!r}"
        f"{f' (margin {a.margin:g})' if a.how == 'seen' else ''}, weights size^{a.power:g}; the mean over the seeds"
    )
    print(f"{'robots':>6} {'filter':>16} {'RMSE [m]':>9} {'vs exact':>8} {'ANEES/dof':>9} {'moved/s':>8} "
          f"{'mates/det':>9} {'largest':>7} {'cpu s':>6}")  # fmt: skip
    for n in map(int, a.robots.split(",")):
        srcs = [scene(n, a.duration, s, a.arena) for s in seeds]
        exact = math.nan
        settings = [(int(k), float(p)) for k in a.cluster.split(",") for p in a.period.split(",") if int(k) < n]
        for K, p in [(n, 0.0), *settings]:
            t = time.process_time()
            rs = [replay(s, K, p, a.how, a.margin, a.power) for s in srcs]
            r = {k: float(np.mean([x[k] for x in rs])) for k in ("rmse", "anees", "moved", "mates")}
            exact = r["rmse"] if K == n else exact
            name = "exact" if K == n else f"K={K}" + (f" every {p:g} s" if p else " fixed")
            vs = "-" if K == n else f"{100 * (r['rmse'] / exact - 1):+.0f}%"
            moved = r["moved"] / n / a.duration
            print(f"{n:>6} {name:>16} {r['rmse']:>9.4f} {vs:>8} {r['anees']:>9.2f} {moved:>8.3f} {r['mates']:>9.1f} "
                  f"{max(x['largest'] for x in rs):>7} {time.process_time() - t:>6.1f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
