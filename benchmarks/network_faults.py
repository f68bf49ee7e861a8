"""Fault table of the live team runtime: team RMSE, ANEES and message counts under injected network faults.

    python benchmarks/network_faults.py [--estimator rdl] [--robots 3] [--duration 30] [--out FILE.md]

Every row starts a fresh team of node processes on 127.0.0.1 (``swarmloc.experiments.team.run_team``) on the same
simulated team (``sim:random``, seed 0), with message loss x delay (plus duplicates 5% and reordering 10% once
delayed), then half the messages duplicated, a node killed and restarted from the belief server, killed and not
restarted, a late joiner, one robot's clock jumping 30 s ahead and 30 s back a third of the way in, and the launcher
itself SIGKILLed. The first row (no faults) is the baseline.
The teams run as fast as they can (``speed`` 0), but for the faults that start a process during the run (``kill``'s
restart, ``late``): at speed 0 the team reads its 30 s source in about a second, before that process is up (a
node's start takes longer), so it ran alone, saw no teammate and exited 3; those rows run at ``--joiner-speed``
(default 1: the source read in real time, the joiner up well before the team ends).
Counts are summed over the nodes' reports: ``lost``/``dup`` injected, ``dropped`` messages rejected on receipt
(stale, duplicate, outdated update, malformed), ``replayed`` history entries re-applied because of late input,
``no reply`` queries that timed out (asked of the server or answered "not found"). NaN: any non-finite belief.
``outcomes`` is ``yes`` when every report's detections each have exactly one outcome (fused + gated + rejected +
unknown + pending = detections, nothing pending). ``left``: processes of the team still running once the run
returned (looked up in /proc by the team's name).
"""

from __future__ import annotations

import argparse
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from swarmloc.evaluation.metrics import evaluate
from swarmloc.experiments.sources import load_source
from swarmloc.experiments.team import run_team, team_result
from swarmloc.net.faults import parse_faults

LINK = [(loss, delay) for loss in (0.0, 0.1, 0.3, 0.5) for delay in (0.0, 0.2, 1.0)]


def team_pids(team: str) -> list[int]:
    """Pids of the running ``swarmloc`` processes whose command line names ``team``."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if team.encode() in cmd and b"swarmloc.cli" in cmd:
            out.append(int(d.name))
    return out


def row(src, spec: str, est: str, faults: str, robots: int, duration: float, waits: dict[str, float],
        speed: float = 0.0) -> dict:  # fmt: skip
    t = time.perf_counter()
    team = f"faults{os.getpid()}"
    tr = run_team(src=src, source=spec, robots=robots, duration=duration, estimator=est, faults=faults,
                  max_wall=600, team=team, speed=speed, **waits)  # fmt: skip
    res = team_result(tr, src, est)
    ev = evaluate(res)
    s = res.stats
    finite = all(np.isfinite(tr_.mean).all() and np.isfinite(tr_.cov).all() for tr_ in res.tracks.values())
    outcomes = all(
        r.stats.get("pending", 0) == 0
        and r.stats.get("detections", 0) == sum(r.stats.get(k, 0) for k in ("fused", "gated", "rejected", "unknown"))
        for r in tr.reports.values()
    )
    f = parse_faults(faults)
    killed = {e["process"] for e in tr.ended if e["how"].startswith("killed by the fault")}  # exit -9 expected
    note = []
    if f.jump is not None:
        others = [r for r in src.robots if r != f.jump[0]]
        o = evaluate(res, others)["team"]
        jumps = sum(r.stats.get("clock_jumps", 0) + r.stats.get("clock_resets", 0) for r in tr.reports.values())
        note.append(f"robot {f.jump[0]}: {jumps} clock jump taken; the others: RMSE {o['pos_rmse']:.3f}, "
                    f"ANEES {o['anees']:.2f}")  # fmt: skip
    for e in tr.ended:
        note.append(f"{e['process']} {e['how']} (exit {e['exit_code']})")
    if f.kill is not None and not f.restart:
        note.append(f"reports from robots {sorted(tr.reports)}")
    return {
        "faults": (faults or "none") + (f" (speed {speed:g})" if speed else ""),
        "pos_rmse": f"{ev['team']['pos_rmse']:.3f}",
        "anees": f"{ev['team']['anees']:.2f}",
        "fused": s["fused"],
        "unknown": s["unknown"],
        "rejected_det": s["rejected"],
        "lost": s.get("net_lost", 0),
        "dup": s.get("net_duplicated", 0),
        "dropped": s.get("messages_rejected", 0) + s.get("net_rejected", 0),
        "replayed": s.get("replayed", 0),
        "no_reply": s.get("net_no_reply", 0),
        "nan": "yes" if not finite else "no",
        "outcomes": "yes" if outcomes else "NO",
        "left": len(team_pids(team)),
        "exit_ok": "yes" if all(c in (0, None) for n, c in tr.exit_codes.items() if n not in killed) else "NO",
        "note": "; ".join(note),
        "wall_s": time.perf_counter() - t,
    }


def launcher_killed_row(spec: str, est: str, robots: int, duration: float, after: float) -> dict:
    """``swarmloc team`` started as a process and SIGKILLed ``after`` s once its nodes run: no result can come (the
    launcher held what it collected); the row says how long its nodes outlived it and what they left."""
    t = time.perf_counter()
    team = f"killed{os.getpid()}"
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "swarmloc.cli", "team", "--source", spec, "--robots", str(robots), "--duration",
               f"{duration:g}", "--estimator", est, "--speed", "1", "--team", team, "--out", out]  # fmt: skip
        launcher = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 60
            while len(team_pids(team)) < robots + 1 and time.monotonic() < deadline and launcher.poll() is None:
                time.sleep(0.05)  # polling /proc, with a deadline
            time.sleep(after)
            launcher.send_signal(signal.SIGKILL)
            launcher.wait()
            t_kill = time.monotonic()
            while team_pids(team) and time.monotonic() < t_kill + 15:
                time.sleep(0.05)
            gone = time.monotonic() - t_kill
            left = team_pids(team)
            files = sorted(p.name for p in Path(out).iterdir())
        finally:
            for pid in team_pids(team):
                os.kill(pid, signal.SIGKILL)
    na = "n/a"
    return {
        "faults": f"launcher SIGKILLed {after:g} s in", "pos_rmse": na, "anees": na, "fused": na, "unknown": na,
        "rejected_det": na, "lost": na, "dup": na, "dropped": na, "replayed": na, "no_reply": na, "nan": na,
        "outcomes": na, "left": len(left), "exit_ok": "n/a (rc -9)",
        "note": f"nodes gone {gone:.1f} s after the launcher; files left in --out: {files or 'none'} (the "
        f"launcher held the beliefs it collected: no partial result)",
        "wall_s": time.perf_counter() - t,
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--estimator", default="rdl")
    ap.add_argument("--robots", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--answer-timeout", type=float, default=0.5, help="seconds a node waits for a reply to a query")
    ap.add_argument("--hold-timeout", type=float, default=0.25, help="seconds a node holds a query to let it settle")
    ap.add_argument("--update-timeout", type=float, default=0.5, help="seconds a node waits for an rdl update")
    ap.add_argument("--joiner-speed", type=float, default=1.0,
                    help="speed of the rows whose faults start a process mid-run (kill's restart, late)")  # fmt: skip
    ap.add_argument("--out", default=None, help="also write the Markdown table here")
    a = ap.parse_args(argv)
    spec = "sim:random"
    src = load_source(spec, robots=a.robots, duration=a.duration, seed=0)
    specs = [""] + [f"loss={lo:g},delay={de:g}" + (",dup=0.05,reorder=0.1" if de else "") for lo, de in LINK[1:]]
    third = a.duration / 3
    specs += ["dup=0.5", f"kill=1@{third:g}", f"killonly=1@{third:g}", f"late=2@{a.duration / 4:g}",
              f"jump=1@{third:g}:30", f"jump=1@{third:g}:-30"]  # fmt: skip
    waits = {"answer_timeout": a.answer_timeout, "hold_timeout": a.hold_timeout, "update_timeout": a.update_timeout}
    rows = []
    for f in specs:
        speed = a.joiner_speed if parse_faults(f).joiner is not None else 0.0
        rows.append(row(src, spec, a.estimator, f, a.robots, a.duration, waits, speed))
        print(f"{rows[-1]['faults']:<40} rmse {rows[-1]['pos_rmse']} anees {rows[-1]['anees']} "
              f"({rows[-1]['wall_s']:.0f} s)", file=sys.stderr)  # fmt: skip
    rows.append(launcher_killed_row(spec, a.estimator, a.robots, a.duration, after=5.0))
    total = sum(r["wall_s"] for r in rows)
    lines = [
        f"Fault table: `python benchmarks/network_faults.py --estimator {a.estimator} --robots {a.robots} "
        f"--duration {a.duration:g}` ({spec}, seed 0; {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores; answer, hold and update timeouts {a.answer_timeout:g}, {a.hold_timeout:g} and "
        f"{a.update_timeout:g} s; {len(rows)} runs, {total / 60:.0f} min)",
        "",
        "| faults | team pos RMSE [m] | ANEES/dof | fused | unknown | rejected det. | lost | dup | dropped msgs "
        "| replayed | no reply | NaN | outcomes | left | clean exit | notes |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['faults']} | {r['pos_rmse']} | {r['anees']} | {r['fused']} | {r['unknown']} | "
            f"{r['rejected_det']} | {r['lost']} | {r['dup']} | {r['dropped']} | {r['replayed']} | {r['no_reply']} | "
            f"{r['nan']} | {r['outcomes']} | {r['left']} | {r['exit_ok']} | {r['note']} |"
        )
    text = "\n".join(lines)
    print(text)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
