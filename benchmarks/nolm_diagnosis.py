"""Why ``diekf``'s truth-free score without landmarks is out of band on some MRCLAM recordings: the
held-out landmark NIS split by robot, by time and into its heading and position parts, the robots' beliefs against
their own landmark snapshots (a pose fit the filter never saw: a truth proxy, 3 dof), and the NIS of the mutual
detections the filter fused.

    python benchmarks/nolm_diagnosis.py --datasets 9,3,2,4,1,6 --out nolm_diag.json [--config X.toml]

Each dataset: the run of ``swarmloc evaluate mrclam DIR --duration 300 --estimators diekf --landmarks off``'s score
(from the truth-free start, to 300 s after the recording's start), with its camera model and ``config``.
``--start`` chooses that start: ``restart`` (the default, ``swarmloc evaluate``'s: every snapshot up to it
filtered as an absolute fix, gated, with restarts after ``--restart-k`` fixes in a row gated:
:func:`~swarmloc.experiments.truthfree.fused_from_snapshots`), ``fused`` (the same without restarts), ``first``
(each robot's first snapshot, dead-reckoned: the start before) or ``latest`` (each robot's latest snapshot).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_mrclam

from swarmloc.config import DEFAULTS, load_config
from swarmloc.datasets.mrclam import load_mrclam, mrclam_events
from swarmloc.estimators import make_team, node_options
from swarmloc.evaluation.heldout import landmark_nis, reading_times
from swarmloc.events import Odometry
from swarmloc.experiments import truthfree
from swarmloc.experiments.mrclam import detection_set, mrclam_stream, yaw_calibrated
from swarmloc.experiments.truthfree import fused_from_snapshots, initial_from_snapshots, landmark_readings
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2, wrap_angle
from swarmloc.runner import run
from swarmloc.sensors.decorrelate import PRIOR_BEARING_STD, PRIOR_RANGE_STD, snapshot_poses

MED1 = 0.454936  # chi-square median, 1 dof
MED2 = 1.386294


def _log_innovations(nodes: list[Any], log: list[tuple[float, int, Any, str, Any]]) -> None:
    """Wrap each node's ``_fuse_one`` to log ``(t, observer, target, outcome, innovation terms)``."""
    for node in nodes:
        node.protocol.innovations = True
        inner = node._fuse_one

        def fuse(s: Any, g: Any, d: Any, sub: Any, inner: Any = inner, node: Any = node) -> Any:
            node.protocol.last_innovation = None
            out = inner(s, g, d, sub)
            log.append((g.t, node.robot, d.target, str(out[1] if isinstance(out[1], str) else out[1][0]),
                        node.protocol.last_innovation))  # fmt: skip
            return out

        node._fuse_one = fuse


def _snapshot_check(tracks: dict[int, Any], snaps: dict[str, np.ndarray], t0: float, t1: float) -> dict[str, Any]:
    """Belief against the snapshot fits: heading error / std, position NEES (2 dof), pose NEES (3 dof)."""
    rows = []
    for r, tr in tracks.items():
        sel = np.flatnonzero((snaps["observer"] == r) & (snaps["t"] > t0) & (snaps["t"] <= t1))
        for i in sel:
            k = int(np.argmin(np.abs(tr.times - snaps["t"][i])))
            if abs(tr.times[k] - snaps["t"][i]) > 1e-3:
                continue
            x, P, z, C = tr.mean[k], tr.cov[k], snaps["pose"][i], snaps["cov"][i]
            c, s = np.cos(x[2]), np.sin(x[2])
            J = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # right perturbation -> world (x, y, theta)
            Pw = J @ P @ J.T + C
            e = np.array([x[0] - z[0], x[1] - z[1], wrap_angle(x[2] - z[2])])
            rows.append(
                (
                    r,
                    snaps["t"][i],
                    e[2],
                    np.sqrt(Pw[2, 2]),
                    float(e[:2] @ np.linalg.solve(Pw[:2, :2], e[:2])),
                    float(e @ np.linalg.solve(Pw, e)),
                    np.hypot(*e[:2]),
                    np.sqrt(np.trace(Pw[:2, :2])),
                )
            )
    a = np.array(rows).reshape(-1, 8)
    out: dict[str, Any] = {"n": len(a)}

    def summary(m: np.ndarray) -> dict[str, float]:
        b = a[m]
        h = (b[:, 2] / b[:, 3]) ** 2
        return {"n": int(m.sum()), "heading_med_ratio": float(np.median(h) / MED1), "heading_mean": float(h.mean()),
                "pos_med_ratio": float(np.median(b[:, 4]) / MED2), "pos_mean_dof": float(b[:, 4].mean() / 2),
                "pose_mean_dof": float(b[:, 5].mean() / 3), "pose_med_ratio": float(np.median(b[:, 5]) / 2.366),
                **{f"{q}_rms_{w}": float(np.sqrt(np.mean(b[:, c] ** 2)))
                   for q, w, c in (("head", "err", 2), ("head", "std", 3), ("pos", "err", 6), ("pos", "std", 7))},
                }  # fmt: skip

    out["all"] = summary(np.ones(len(a), bool))
    out["robots"] = {int(r): summary(a[:, 0] == r) for r in np.unique(a[:, 0])}
    edges = np.arange(t0, t1 + 50.0, 50.0)
    out["time"] = {f"{e - t0:.0f}": summary((a[:, 1] > e) & (a[:, 1] <= e + 50)) for e in edges[:-1]
                   if ((a[:, 1] > e) & (a[:, 1] <= e + 50)).sum() > 3}  # fmt: skip
    out["series"] = a.tolist()
    return out


def _mutual(log: list[tuple[float, int, Any, str, Any]], robots: list[int]) -> dict[str, Any]:
    """The mutual detections' NIS: per dof median ratio and mean, the prediction share, gated count."""
    rows = [(t, o, tg, out, inn) for t, o, tg, out, inn in log if tg in robots]
    inn = [x[4] for x in rows if x[4] is not None]
    e = np.array([i.e for i in inn])
    b = np.array([(i.m - i.a) / i.m for i in inn])
    outcomes: dict[str, int] = {}
    for x in rows:
        outcomes[x[3]] = outcomes.get(x[3], 0) + 1
    hi = b >= 0.5
    return {"n": len(inn), "outcomes": outcomes, "nis_med_ratio": float(np.median(e) / MED2),
            "anis": float(e.mean() / 2), "share_med": float(np.median(b)),
            "pred_dominated": int(hi.sum()),
            "nis_med_ratio_pred": float(np.median(e[hi]) / MED2) if hi.any() else float("nan"),
            "anis_pred": float(e[hi].mean() / 2) if hi.any() else float("nan")}  # fmt: skip


def latest_start(data: Any, ds: Any, config: Any) -> tuple[float, dict[int, Any]]:
    """As :func:`~swarmloc.experiments.truthfree.initial_from_snapshots` (the same ``t0``: every robot's first
    snapshot in), but each robot starts from its *latest* snapshot at or before ``t0``, not its first: the least
    dead reckoning to ``t0``."""
    poses = snapshot_poses(ds, PRIOR_RANGE_STD, PRIOR_BEARING_STD)
    t0 = max(float(poses["t"][i]) for i in truthfree._first_snapshots(data, poses).values())
    odo = [e for e in mrclam_events(data, landmarks=False, robot_measurements=False) if isinstance(e, Odometry)]
    out = {}
    for r in data.robots:
        i = int(np.flatnonzero((poses["t"] <= t0) & (poses["observer"] == r))[-1])
        ts, belief = truthfree.snapshot_belief(poses, i)
        if ts >= t0:
            out[r] = belief
            continue
        mine = [e for e in odo if e.robot == r and ts <= e.stamp <= t0]
        dr = make_team("dr", {r: belief}, **node_options("dr", config, None, ts))
        tr = run(dr, mine, record_times=[t0]).tracks[r]
        out[r] = GroupGaussian(SE2, SE2.from_xytheta(tr.mean[-1]), tr.cov[-1], validate=False)
    return t0, out


def fused_start(
    data: Any, ds: Any, config: Any, restart: int | None = None, inflate: float = 1.0
) -> tuple[float, dict[int, Any]]:
    """:func:`~swarmloc.experiments.truthfree.fused_from_snapshots` (the same ``t0`` as
    :func:`~swarmloc.experiments.truthfree.initial_from_snapshots`): each robot's one-robot ``diekf`` from its first
    snapshot to ``t0`` fuses every later snapshot as an absolute pose fix, gated at chi-square 0.99 (3 dof);
    ``restart`` (k; None, the default here: never) re-acquires a robot after k fixes in a row gated (``--start
    restart``). The counts go to :data:`FUSED_COUNTS`."""
    t0, out, counts = fused_from_snapshots(data, ds, config, restart, inflate)
    for r, n in counts.items():
        FUSED_COUNTS[(data.name, r)] = n
        print(f"  fused start {data.name} robot {r}:", n, flush=True)
    return t0, out


FUSED_COUNTS: dict[tuple[str, int], dict[str, int]] = {}
"""Per ``(dataset name, robot)`` of the last :func:`fused_start`: the snapshots offered and the node's counters."""

START = {
    "first": initial_from_snapshots,
    "latest": latest_start,
    "fused": fused_start,
    "restart": functools.partial(fused_start, restart=3),
}


def diagnose(
    k: int, root: Path, config: Any, duration: float, name: str = "diekf", start: str = "restart", yaw: bool = False
) -> dict[str, Any]:
    """The diagnosis of estimator ``name`` on dataset ``k``, landmarks off (module docstring)."""
    data = load_mrclam(root / f"MRCLAM_Dataset{k}")
    events, camera = mrclam_stream(data, config, duration, landmarks=False)
    if yaw:
        config = yaw_calibrated(data, camera, config)[0]
    ds = detection_set(data)
    t0, initial = START[start](data, ds, config)
    t_end = min(data.t_end, data.t_start + duration, t0 + 300.0)
    span = [e for e in events if t0 <= e.stamp <= t_end]
    readings = landmark_readings(data, t0, t_end)
    snaps = snapshot_poses(ds, camera.range.std, camera.bearing.std)
    ts = snaps["t"][(snaps["t"] > t0) & (snaps["t"] <= t_end)]
    rec = np.unique(np.concatenate([reading_times(readings), ts]))
    nodes = make_team(name, initial, **node_options(name, config, data.landmarks, t0))
    log: list[tuple[float, int, Any, str, Any]] = []
    if name == "diekf":
        _log_innovations(nodes, log)
    res = run(nodes, span, record_times=rec, truth=data.truth_at if data.has_truth else None, name=name)
    std = (camera.range.std, camera.bearing.std)
    per_robot, allnis, times, obs = {}, [], [], []
    for r, tr in res.tracks.items():
        mine = [d for d in readings if d.observer == r]
        nis = landmark_nis(tr.times, tr.mean, tr.cov, mine, data.landmarks, std)
        ok = np.isfinite(nis)
        per_robot[r] = {"n": int(ok.sum()), "nis_ratio": float(np.median(nis[ok]) / MED2)}
        allnis.append(nis[ok])
        times.append(np.array([d.t for d in mine])[ok])
        obs.append(np.full(ok.sum(), r))
    nis, tt, oo = np.concatenate(allnis), np.concatenate(times), np.concatenate(obs)
    edges = np.arange(t0, t_end + 50.0, 50.0)
    by_time = {f"{e - t0:.0f}": float(np.median(nis[(tt > e) & (tt <= e + 50)]) / MED2) for e in edges[:-1]
               if ((tt > e) & (tt <= e + 50)).sum() > 3}  # fmt: skip
    out: dict[str, Any] = {"dataset": k, "t0_s": t0 - data.t_start, "span_s": t_end - t0,
                           "score": float(np.median(nis) / MED2), "anis": float(nis.mean() / 2),
                           "beyond_gate": float(np.mean(nis > 11.618)), "readings": int(nis.size),
                           "robots": per_robot, "time": by_time, "camera_std": std,
                           "snapshots": _snapshot_check(res.tracks, snaps, t0, t_end),
                           "mutual": _mutual(log, list(data.robots)) if log else {},
                           "heldout_series": np.column_stack([oo, tt, nis]).tolist()}  # fmt: skip
    if data.has_truth:
        rec_t = np.arange(t0 + 1.0, t_end, 1.0)
        res2 = run(make_team(name, initial, **node_options(name, config, data.landmarks, t0)), span,
                   record_times=rec_t, truth=data.truth_at, name=name)  # fmt: skip
        h, p = [], []
        for tr in res2.tracks.values():
            good = np.isfinite(tr.truth).all(axis=1)
            for x, P, z in zip(tr.mean[good], tr.cov[good], tr.truth[good], strict=True):
                c, s = np.cos(x[2]), np.sin(x[2])
                J = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                Pw = J @ P @ J.T
                e = np.array([x[0] - z[0], x[1] - z[1], wrap_angle(x[2] - z[2])])
                h.append(e[2] ** 2 / Pw[2, 2])
                p.append(float(e[:2] @ np.linalg.solve(Pw[:2, :2], e[:2])))
        out["truth"] = {"heading_nees": float(np.mean(h)), "pos_nees_dof": float(np.mean(p) / 2)}
    return out


def windows(
    k: int, root: Path, config: Any, stride: float, span: float = 300.0, start: str = "restart", yaw: bool = False
) -> list[dict[str, Any]]:
    """The truth-free score (landmarks off) of ``diekf`` over windows of ``span`` s starting every ``stride`` s, each
    from its own truth-free start (the first snapshots after the window's start); with truth, its ANEES/dof too."""
    from swarmloc.evaluation.metrics import evaluate
    from swarmloc.experiments.truthfree import truth_free_score

    data = load_mrclam(root / f"MRCLAM_Dataset{k}")
    events, camera = mrclam_stream(data, config, None, landmarks=False)
    if yaw:
        config = yaw_calibrated(data, camera, config)[0]
    ds = detection_set(data)
    out = []
    for T in np.arange(data.t_start, data.t_end - span + 1e-9, stride):
        sub = dataclasses.replace(data, t_start=float(T))
        try:
            t0, initial = START[start](sub, ds, config)
        except truthfree.NoStart:  # a window with no truth-free start is skipped
            continue
        sc = truth_free_score(sub, ds, events, "diekf", config, (camera.range.std, camera.bearing.std), False,
                              float(T) + span, start=(t0, initial))  # fmt: skip
        row = {"start_s": float(T - data.t_start), "t0_s": sc["t0_s"], "score": sc["nis_ratio"], "anis": sc["anis"],
               "readings": sc["readings"]}  # fmt: skip
        if data.has_truth:
            rec = np.arange(t0 + 1.0, float(T) + span, 1.0)
            res = run(make_team("diekf", initial, **node_options("diekf", config, data.landmarks, t0)),
                      [e for e in events if t0 <= e.stamp <= float(T) + span], record_times=rec, truth=data.truth_at,
                      name="diekf")  # fmt: skip
            row["anees"] = float(evaluate(res)["team"]["anees"])
        print(k, {q: round(v, 3) for q, v in row.items()}, flush=True)
        out.append(row)
    return out


def study_rows(datasets: list[int], root: Path, start: str) -> dict[int, Any]:
    """The leave-one-dataset-out study's ``diekf`` row per dataset (:mod:`swarmloc_studies.lodo`: camera model
    fitted on the other recordings, 200 s, landmark folds held out), landmarks on and off, with the study's start
    replaced by :data:`START` ``[start]``: RMSE [m] and ANEES/dof where there is truth, the truth-free score."""
    import swarmloc_studies.lodo as lodo

    datas = {k: load_mrclam(root / f"MRCLAM_Dataset{k}", require=("measurements",)) for k in lodo.DATASETS}
    ms = lodo.model_scores({k: lodo.detection_set(d) for k, d in datas.items()})
    chosen = ms["chosen"]
    out: dict[int, Any] = {}
    for k in datasets:
        model = ms["models"][k][chosen]
        ref = lodo.own_std(model, ms["folds"][k][chosen])
        for lm in (True, False):
            r = lodo.filter_scores(datas[k], model, ["diekf"], lm, 200.0, holdout=3, reference_std=ref,
                                   start=START[start])["diekf"]  # fmt: skip
            row = {x: round(r[x], 3) for x in ("pos_rmse", "anees", "nis_ratio_ref", "nis_ratio") if x in r}
            out.setdefault(k, {})["on" if lm else "off"] = row
            print(start, k, "on" if lm else "off", row, flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_mrclam(ap)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--datasets", default="9,3,2,4,1,6")
    ap.add_argument("--config", type=Path, default=None)
    ap.add_argument("--estimator", default="diekf")
    ap.add_argument("--start", choices=sorted(START), default="restart")
    ap.add_argument("--restart-k", type=int, default=3, help="--start restart: gated fixes in a row before a restart")
    ap.add_argument("--inflate", type=float, default=1.0, help="--start restart: the seed fix's covariance scale")
    ap.add_argument("--calibrate-yaw", action="store_true", help="as swarmloc evaluate's (on the whole recording)")
    ap.add_argument("--out", type=Path, default=Path("nolm_diag.json"))
    ap.add_argument("--windows", type=float, default=0.0, help="stride [s]: score 300 s windows (no diagnosis)")
    study = "the leave-one-dataset-out study's filter row (200 s, camera held out) from --start"
    ap.add_argument("--study", action="store_true", help=study)
    a = ap.parse_args()
    START["restart"] = functools.partial(fused_start, restart=a.restart_k, inflate=a.inflate)
    config = DEFAULTS if a.config is None else load_config(a.config)
    out: dict[int, Any] = {}
    if a.study:
        out = study_rows([int(x) for x in a.datasets.split(",")], a.mrclam, a.start)
        a.out.write_text(json.dumps(out, default=float))
        return
    if a.windows:
        for k in (int(x) for x in a.datasets.split(",")):
            out[k] = windows(k, a.mrclam, config, a.windows, start=a.start, yaw=a.calibrate_yaw)
        a.out.write_text(json.dumps(out, default=float))
        return
    for k in (int(x) for x in a.datasets.split(",")):
        r = diagnose(k, a.mrclam, config, a.duration, a.estimator, a.start, a.calibrate_yaw)
        out[k] = r
        short = {x: r[x] for x in ("score", "anis", "beyond_gate", "readings", "t0_s", "span_s")}
        print(k, json.dumps(short), flush=True)
        print("  robots", {q: round(v["nis_ratio"], 2) for q, v in r["robots"].items()}, "time",
              {q: round(v, 2) for q, v in r["time"].items()})  # fmt: skip
        sn = r["snapshots"]["all"]
        print("  snapshots", {q: round(v, 3) for q, v in sn.items()})
        print("  snap robots", {q: (round(v["heading_med_ratio"], 2), round(v["pos_med_ratio"], 2))
                                for q, v in r["snapshots"]["robots"].items()})  # fmt: skip
        print("  snap time", {q: (round(v["heading_med_ratio"], 2), round(v["pos_med_ratio"], 2))
                              for q, v in r["snapshots"]["time"].items()})  # fmt: skip
        print("  mutual", r["mutual"], r.get("truth", ""), flush=True)
    a.out.write_text(json.dumps(out, default=float))


if __name__ == "__main__":
    main()
