"""``swarmloc node``, ``swarmloc server`` and ``swarmloc team``: the processes of a live team and their launcher.

:func:`node_main` runs one robot (its own events of a source, one node of a distributed estimator) on a Zenoh
peer; :func:`server_main` runs the belief server; :func:`run_team` starts ``N`` node processes (and the server)
as Zenoh peers on 127.0.0.1, collects the beliefs they publish and scores them like ``swarmloc evaluate``. It
stops every process it started when the team is done, on an error, on Ctrl-C and on its time limit.
"""

from __future__ import annotations

import logging
import math
import os
import queue
import signal
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.config import Config
from swarmloc.events import Event, Odometry
from swarmloc.net.faults import Faults, parse_faults
from swarmloc.net.schema import Belief, Progress, Rejected, Report, decode
from swarmloc.net.transport import check_team, free_ports, open_session, robot_key

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------------- one node
def distributed_class(estimator: str) -> type:
    """The node class of a distributed ``estimator`` (one node per robot); ValueError naming the choices else."""
    from swarmloc.estimators import ESTIMATORS
    from swarmloc.node import RobotNode

    cls = ESTIMATORS.get(estimator)
    if cls is None:
        raise ValueError(f"unknown estimator {estimator!r}; choose from {sorted(ESTIMATORS)}")
    networked = [k for k, c in ESTIMATORS.items() if issubclass(c, RobotNode) and c.distributed and c.over_network]
    if not issubclass(cls, RobotNode) or not cls.distributed:
        raise ValueError(
            f"{estimator!r} is not a distributed estimator (one node per robot): run it in-process with "
            f"'swarmloc evaluate'; over the network choose from {networked}"
        )
    if not cls.over_network:
        raise ValueError(
            f"{estimator!r} needs a broadcast to every teammate per update, which the network driver does not carry "
            f"yet: run it in-process with 'swarmloc evaluate'; over the network choose from {networked}"
        )
    return cls


def make_node(estimator: str, robot: int, initial: Any, config: Config, landmarks: Any) -> Any:
    """The node of ``robot`` for a distributed ``estimator`` with the options ``swarmloc evaluate`` uses."""
    from swarmloc.estimators import node_options

    return distributed_class(estimator)(robot, initial, **node_options(estimator, config, landmarks))


def resume_events(events: Sequence[Event], t: float) -> list[Event]:
    """A robot's events from ``t`` on: the command in force at ``t`` clipped to start there, later ones as they are."""
    out: list[Event] = []
    for e in events:
        if isinstance(e, Odometry):
            if e.t0 >= t:
                out.append(e)
            elif e.t1 > t:
                out.append(Odometry(e.robot, t, e.t1, e.v, e.w))
        elif e.stamp >= t:
            out.append(e)
    return out


def node_main(
    *,
    robot: int,
    team: str,
    source: str,
    estimator: str,
    config: Config | None = None,
    robots: int = 3,
    duration: float | None = None,
    seed: int = 0,
    speed: float = 0.0,
    lag: float = 0.5,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    zenoh_config: str | None = None,
    use_server: bool = False,
    resume: bool = False,
    faults: str | Faults | None = None,
    wait_for: Sequence[int] | None = None,
    answer_timeout: float = 2.0,
    ros_domain: int | None = None,
    max_wall: float | None = None,
    out: str | os.PathLike[str] | None = None,
) -> Report:
    """Run robot ``robot`` of ``source`` as one Zenoh peer until the team is done; returns its report. With
    ``out``: also write ``robot<N>.tum`` (its final beliefs) and ``robot<N>.json`` (its report) there."""
    from swarmloc.experiments.sources import load_source
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.lie import SE2
    from swarmloc.net.process import NetNode

    check_team(team)
    src = load_source(source, robots=robots, duration=duration, seed=seed, config=config)
    if robot not in src.initial:
        raise ValueError(f"robot {robot} is not in source {source!r} (robots {src.robots})")
    events = src.own_events(robot)
    initial = src.initial[robot]
    record_times = src.record_times()
    session = open_session(listen, connect, zenoh_config)
    finals: dict[float, Belief] = {}
    try:
        if resume:
            b = _latest_from_server(session, team, src.robots, robot)
            initial = GroupGaussian(SE2, np.reshape(b.mean, (3, 3)), np.reshape(b.cov, (3, 3)))
            events = resume_events(events, b.stamp)
            record_times = record_times[record_times > b.stamp]
            t0 = b.stamp
            log.warning("robot %s: resumed from the server's belief at %.3f s", robot, t0)
        else:
            stamps = [e.t0 if isinstance(e, Odometry) else e.stamp for e in events]
            t0 = min(stamps) if stamps else src.t_start
        node = make_node(estimator, robot, initial, src.config, src.landmarks)
        node.start(t0)
        net = NetNode(
            node,
            events,
            session=session,
            team=team,
            roster=src.robots,
            record_times=record_times,
            speed=speed,
            lag=lag,
            answer_timeout=answer_timeout,
            use_server=use_server,
            faults=parse_faults(faults) if isinstance(faults, str | None) else faults,
            wait_for=wait_for,
            ros_domain=ros_domain,
            on_belief=lambda b: finals.__setitem__(b.stamp, b) if b.final else None,
        )
        _stop_on_sigterm(net.stop)
        report = net.run(max_wall=max_wall)
        if out is not None:
            import json

            import msgspec

            from swarmloc.datasets.tum import write_tum

            folder = Path(out)
            folder.mkdir(parents=True, exist_ok=True)
            bs = [finals[t] for t in sorted(finals)]
            xyt = SE2.to_xytheta(np.array([b.mean for b in bs]).reshape(-1, 3, 3)).reshape(-1, 3)
            write_tum(folder / f"robot{robot}.tum", np.array([b.stamp for b in bs]), xyt)
            (folder / f"robot{robot}.json").write_text(json.dumps(msgspec.to_builtins(report), indent=2))
        return report
    finally:
        session.close()


def _latest_from_server(session: Any, team: str, roster: Sequence[int], robot: int, timeout: float = 5.0) -> Belief:
    from swarmloc.net.transport import server_key

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for reply in session.get(f"{server_key(team)}?latest={robot}", timeout=1.0):
            if reply.ok is None:
                continue
            try:
                env = decode(reply.ok.payload.to_bytes(), team, roster)
            except Rejected:
                continue
            if isinstance(env.body, Belief) and env.body.robot == robot:
                return env.body
        time.sleep(0.1)
    raise RuntimeError(f"robot {robot}: no belief to resume from on the belief server of team {team!r}")


def server_main(
    *,
    team: str,
    roster: Sequence[int],
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    zenoh_config: str | None = None,
    max_wall: float | None = None,
) -> None:
    """Run the belief server of ``team`` until SIGTERM / Ctrl-C (or ``max_wall`` s)."""
    from swarmloc.net.server import ServerProcess

    check_team(team)
    session = open_session(listen, connect, zenoh_config)
    try:
        sp = ServerProcess(session, team, roster)
        _stop_on_sigterm(sp.stop)
        try:
            sp.run(max_wall=max_wall)
        except KeyboardInterrupt:
            pass
    finally:
        session.close()


def _stop_on_sigterm(stop: Any) -> None:
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop())


# ---------------------------------------------------------------------------------------------------- the team
@dataclass
class TeamRun:
    """What :func:`run_team` collected: the best belief per robot and stamp, the nodes' reports, and counts."""

    beliefs: dict[tuple[int, float], Belief] = field(default_factory=dict)
    reports: dict[int, Report] = field(default_factory=dict)
    counts: Counter[str] = field(default_factory=Counter)
    wall_s: float = 0.0
    exit_codes: dict[str, int | None] = field(default_factory=dict)

    def keep(self, b: Belief) -> None:
        k = (b.robot, b.stamp)
        old = self.beliefs.get(k)
        if old is None or (b.final, b.rev) > (old.final, old.rev):
            self.beliefs[k] = b

    def tracks(self, truth: Any = None) -> dict[int, Any]:
        """Recorded beliefs per robot as :class:`~swarmloc.runner.RobotTrack` (truth NaN unless ``truth``)."""
        from swarmloc.lie import SE2
        from swarmloc.runner.result import RobotTrack

        out = {}
        for r in sorted({k[0] for k in self.beliefs}):
            bs = sorted((b for k, b in self.beliefs.items() if k[0] == r), key=lambda b: b.stamp)
            times = np.array([b.stamp for b in bs])
            means = SE2.to_xytheta(np.array([b.mean for b in bs]).reshape(-1, 3, 3)).reshape(-1, 3)
            covs = np.array([b.cov for b in bs]).reshape(-1, 3, 3)
            tr = np.full((times.size, 3), np.nan)
            if truth is not None and times.size:
                try:
                    tr = np.asarray(truth(r, times), dtype=float).reshape(-1, 3)
                except ValueError:
                    pass
            out[r] = RobotTrack(times, means, covs, tr)
        return out


def _python() -> list[str]:
    return [sys.executable, "-m", "swarmloc.cli"]


def run_team(
    *,
    src: Any = None,
    robots: int = 3,
    source: str = "sim:random",
    estimator: str = "expfusion",
    duration: float | None = None,
    seed: int = 0,
    config_file: str | None = None,
    server: bool = False,
    faults: str | None = None,
    speed: float = 0.0,
    lag: float = 0.5,
    answer_timeout: float = 2.0,
    team: str | None = None,
    timeout: float = 600.0,
    ros_domain: int | None = None,
    log_dir: str | os.PathLike[str] | None = None,
    verbose: bool = False,
    connect_extra: Sequence[str] = (),
) -> TeamRun:
    """Start the team's processes on 127.0.0.1, collect their beliefs and reports, stop them all.

    ``robots`` applies to simulated sources (a dataset's robots are its own). Faults: :mod:`swarmloc.net.faults`;
    a kill fault needs the belief server (started automatically). ``connect_extra``: endpoints every process also
    connects to (a Zenoh router, e.g. ROS 2's ``rmw_zenohd`` on ``tcp/127.0.0.1:7447``).
    """
    from swarmloc.experiments.sources import load_source

    f = parse_faults(faults)
    team = check_team(team or f"team{os.getpid()}")
    distributed_class(estimator)  # refuse a centralized or unknown estimator before starting anything
    if src is None:
        src = load_source(source, robots=robots, duration=duration, seed=seed)
    src_robots = src.robots
    server = server or f.kill is not None
    names = [f"robot{r}" for r in src_robots] + (["server"] if server else [])
    ports = dict(zip([*names, "collector"], free_ports(len(names) + 1), strict=True))
    ep = {k: f"tcp/127.0.0.1:{p}" for k, p in ports.items()}
    common = ["--team", team]

    def args_for(name: str, extra: Sequence[str] = ()) -> list[str]:
        others = [ep[k] for k in ep if k != name] + list(connect_extra)  # e.g. a Zenoh router (ROS 2)
        out = [*common, "--listen", ep[name], "--connect", ",".join(others)]
        return [*out, *extra]

    node_common = ["--source", source, "--estimator", estimator, "--robots", str(robots), "--seed", str(seed),
                   "--speed", str(speed), "--lag", str(lag), "--answer-timeout", str(answer_timeout)]  # fmt: skip
    if duration is not None:
        node_common += ["--duration", str(duration)]
    if config_file:
        node_common += ["--config", str(config_file)]
    if server:
        node_common.append("--use-server")
    if f.link:
        node_common += ["--faults", Faults(loss=f.loss, delay=f.delay, reorder=f.reorder, dup=f.dup,
                                           seed=f.seed).to_spec()]  # fmt: skip
    if ros_domain is not None:
        node_common += ["--ros-domain", str(ros_domain)]
    if verbose:
        node_common.append("--verbose")
    late = f.late[0] if f.late is not None else None
    if late is not None and late not in src_robots:
        raise ValueError(f"faults: late robot {late} is not in the team {src_robots}")
    if f.kill is not None and f.kill[0] not in src_robots:
        raise ValueError(f"faults: killed robot {f.kill[0]} is not in the team {src_robots}")
    wait_for = [r for r in src_robots if r != late]

    logs = Path(log_dir) if log_dir is not None else None
    if logs is not None:
        logs.mkdir(parents=True, exist_ok=True)
    procs: dict[str, subprocess.Popen] = {}
    run = TeamRun()

    def spawn(name: str, cmd: list[str]) -> None:
        out = open(logs / f"{name}.log", "ab") if logs is not None else subprocess.DEVNULL  # noqa: SIM115
        procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT if logs else out,
                                       start_new_session=True)  # fmt: skip
        if logs is not None:
            out.close()

    def node_cmd(r: int, resume: bool = False) -> list[str]:
        # a restarted or late robot joins a running team: it waits for nobody
        wait = "none" if resume or r == late else ",".join(map(str, wait_for)) or "none"
        extra = [*node_common, "--robot", str(r), "--wait-for", wait]
        return [*_python(), "node", *args_for(f"robot{r}", extra), *(["--resume"] if resume else [])]

    session = open_session([ep["collector"]], [ep[k] for k in ep if k != "collector"])
    inq: queue.SimpleQueue = queue.SimpleQueue()
    subs = [
        session.declare_subscriber(robot_key(team, "*", what), handler=lambda x: inq.put(("sample", x)))
        for what in ("belief", "report", "progress")
    ]
    roster = frozenset(src_robots)
    progress: dict[int, float] = {}

    def collect(sample: Any) -> None:
        """Keep a published belief, report or progress announcement (a bad payload is counted and dropped)."""
        try:
            b = decode(sample.payload.to_bytes(), team, roster, server_ok=False).body
        except Rejected as exc:
            run.counts["rejected"] += 1
            log.debug("team: dropped a message: %s", exc.reason)
            return
        if isinstance(b, Belief):
            run.keep(b)
        elif isinstance(b, Report):
            run.reports[b.robot] = b
        elif isinstance(b, Progress) and math.isfinite(b.t):
            progress[b.robot] = max(progress.get(b.robot, -math.inf), b.t)

    t0 = time.monotonic()
    killed = restarted = joined = False
    t_first = src.t_start
    try:
        if server:
            spawn("server", [*_python(), "server", *args_for("server"), "--roster", ",".join(map(str, src_robots))])
        for r in src_robots:
            if r != late:
                spawn(f"robot{r}", node_cmd(r))
        while True:
            if time.monotonic() - t0 > timeout:
                run.counts["timed_out"] = 1
                log.warning("team: time limit of %.0f s reached; stopping every process", timeout)
                break
            try:
                kind, x = inq.get(timeout=0.1)
            except queue.Empty:
                kind, x = None, None
            if kind is not None:
                collect(x)
            if f.late is not None and not joined:
                others = [progress.get(r, -math.inf) for r in wait_for]
                # join once the others have read that far, or once they are all gone (a join time past the end)
                gone = all(procs[f"robot{r}"].poll() is not None for r in wait_for)
                if (others and min(others) >= t_first + f.late[1]) or gone:
                    spawn(f"robot{late}", node_cmd(late))
                    joined = True
                    run.counts["late_joined"] = 1
            if f.kill is not None and not killed:
                k, tk = f.kill
                if progress.get(k, -math.inf) >= t_first + tk:
                    procs[f"robot{k}"].kill()
                    procs[f"robot{k}"].wait()
                    killed = True
                    run.counts["killed"] = 1
            if killed and not restarted:
                time.sleep(0.5)
                spawn(f"robot{f.kill[0]}", node_cmd(f.kill[0], resume=True))
                restarted = True
                run.counts["restarted"] = 1
            nodes = [p for n, p in procs.items() if n.startswith("robot")]
            all_started = (late is None or joined) and (f.kill is None or restarted or killed is False)
            if all_started and all(p.poll() is not None for p in nodes) and len(nodes) == len(src_robots):
                # drain what is still queued
                while True:  # what is still queued
                    try:
                        collect(inq.get(timeout=0.3)[1])
                    except queue.Empty:
                        break
                break
    finally:
        for s in subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001
                pass
        stop_all(procs)
        run.exit_codes = {n: p.returncode for n, p in procs.items()}
        session.close()
        run.wall_s = time.monotonic() - t0
    return run


def stop_all(procs: dict[str, subprocess.Popen] | Iterable[subprocess.Popen], grace: float = 3.0) -> None:
    """SIGTERM every process still running (its whole session: start them with ``start_new_session=True``), then
    SIGKILL what is left after ``grace`` s; reap them all."""
    procs = list(procs.values()) if isinstance(procs, dict) else list(procs)
    for p in procs:
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
    end = time.monotonic() + grace
    for p in procs:
        try:
            p.wait(timeout=max(0.0, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait()


def team_result(run: TeamRun, src: Any, estimator: str) -> Any:
    """The collected run as a :class:`~swarmloc.runner.RunResult` (node counters summed over the reports; network
    counters under ``net_*``)."""
    from swarmloc.runner.result import RunResult

    stats: Counter[str] = Counter()
    reasons: Counter[str] = Counter()
    for rep in run.reports.values():
        stats.update(rep.stats)
        reasons.update(rep.reasons)
        stats.update({f"net_{k}": v for k, v in rep.net.items()})
        reasons.update({f"network: {k}": v for k, v in rep.net_reasons.items()})
    for k in ("detections", "fused", "gated", "rejected", "unknown", "pending", "odometry", "messages"):
        stats.setdefault(k, 0)
    stats["recorded"] = len(run.beliefs)
    stats["recorded_provisional_only"] = sum(not b.final for b in run.beliefs.values())
    stats["reports"] = len(run.reports)
    stats.update(run.counts)
    return RunResult(estimator, run.tracks(src.truth), run.wall_s, dict(stats), len(src.events), reasons, {})


def write_team_report(run: TeamRun, src: Any, estimator: str, out_dir: str | os.PathLike[str], extra: dict) -> dict:
    """Score the run against the source's truth and write ``team.json``/``team.md``, TUM files and figures (the
    layout of ``swarmloc evaluate``)."""
    from swarmloc.evaluation.metrics import anees_bounds, evaluate
    from swarmloc.experiments.evaluate import write_report

    res = team_result(run, src, estimator)
    truth = src.truth is not None
    ev = evaluate(res) if truth else {"estimator": estimator, "robots": {}, "team": None}
    duration = float(src.t_end - src.t_start)
    ev.update(wall_time_s=run.wall_s, x_real_time=duration / run.wall_s if run.wall_s > 0 else math.inf,
              stats=res.stats, reasons=dict(res.reasons), timing={}, accounted=res.accounted())  # fmt: skip
    ev["robots"] = {str(k): v for k, v in ev["robots"].items()}
    n_rec = sum(tr.times.size for tr in res.tracks.values())
    report = {
        "title": f"live team over Zenoh: {src.spec}, {estimator}",
        "robots": src.robots,
        "duration_s": duration,
        "n_events": len(src.events),
        "config": src.config.to_dict(),
        "truth": truth,
        "estimators": {estimator: ev},
        "anees_bounds_if_independent": anees_bounds(max(n_rec, 1)),
        **extra,
    }
    write_report(out_dir, "team", report, {estimator: res}, src.t_start)
    return report
