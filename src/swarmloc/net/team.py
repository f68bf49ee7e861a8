"""``swarmloc team``'s launcher: a live team of node processes on 127.0.0.1, and what they publish.

:func:`launch_team` starts one ``swarmloc node`` process per robot of a source (and the belief server) as Zenoh
peers on 127.0.0.1, applies the process faults (a robot killed and restarted, a late joiner), collects the beliefs,
reports and progress the nodes publish, and stops every process it started when the team is done, on an error, on
Ctrl-C and on its time limit. Scoring the collected run is the evaluation's (:mod:`swarmloc.experiments.team`).

Every process gets its own key and the team's roster (:class:`~swarmloc.net.auth.TeamKeys`, made in a temporary
folder unless ``keys_dir`` names one): what they send is signed, and the collector keeps only what a roster robot
signed on its own keys, stamped at one of the run's record times (anything else is counted ``collector_rejected``,
an authentication failure also ``collector_auth_<category>``, with its reason in ``reasons``).
"""

from __future__ import annotations

import json
import logging
import math
import os
import queue
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from contextlib import AbstractContextManager, nullcontext, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Unpack

import numpy as np

from swarmloc.datasets.source import Source
from swarmloc.events import Detection
from swarmloc.net.auth import COLLECTOR, Refusals, TeamKeys, open_envelope
from swarmloc.net.entry import hosted_class, map_answers, network_class
from swarmloc.net.faults import Faults, parse_faults
from swarmloc.net.intake import COLLECTOR_BUDGET, Intake, vouch_for
from swarmloc.net.schema import SERVER, Belief, Lines, MapAnswer, Progress, Rejected, Report
from swarmloc.net.settings import NetSettings
from swarmloc.net.teamlink import Presence
from swarmloc.net.timeouts import ANSWER_RETRIES, TIMEOUTS, Waits
from swarmloc.net.transport import (
    check_team,
    client_config,
    free_ports,
    open_session,
    robot_key,
    router_mesh,
    server_key,
    team_scope,
)  # fmt: skip

log = logging.getLogger(__name__)

COLLECT_AFTER_END = 3.0
"""[s] wall time at most the launcher collects what is still queued once every node has ended."""


@dataclass
class TeamRun:
    """What :func:`launch_team` collected: the best belief per robot and stamp, the nodes' reports, and counts
    (with the reasons of the messages the collector refused)."""

    beliefs: dict[tuple[int, float], Belief] = field(default_factory=dict)
    reports: dict[int, Report] = field(default_factory=dict)
    counts: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)
    wall_s: float = 0.0
    exit_codes: dict[str, int | None] = field(default_factory=dict)
    run_id: str = ""
    """The run's id, in every key expression with the team's name (:func:`~swarmloc.net.transport.team_scope`)."""
    ended: list[dict[str, Any]] = field(default_factory=list)
    """Every process that ended with a non-zero exit code, in order: ``process`` (``robot<N>``, ``server``),
    ``pid``, ``exit_code``, ``how`` (died, killed by a fault and restarted, stopped by the launcher) and ``said``
    (the last lines it wrote, for a process that exited with an error)."""
    lines: list[Lines] = field(default_factory=list)
    """Every robot's :class:`~swarmloc.net.schema.Lines` (a source with range scans), as received."""
    map: MapAnswer | None = None
    """The belief server's fused line map, asked for once every node has ended (None: no server, or no answer)."""
    delayed: dict[tuple[int, float], Belief] = field(default_factory=dict)
    """A smoother team's delayed output (``fls`` / ``flsd`` with ``delayed_output``): the latest revision per robot
    and pose stamp (:mod:`swarmloc.net.publishing`)."""

    def keep(self, b: Belief, delayed: bool = False) -> None:
        into = self.delayed if delayed else self.beliefs
        k = (b.robot, b.stamp)
        old = into.get(k)
        if old is None or (b.final, b.rev) > (old.final, old.rev):
            into[k] = b

    def tracks(self, truth: Any = None, delayed: bool = False) -> dict[int, Any]:
        """Recorded beliefs (``delayed``: the delayed output) per robot as :class:`~swarmloc.runner.RobotTrack`
        (truth NaN unless ``truth``)."""
        from swarmloc.datasets.tum import pose7
        from swarmloc.lie import SE2
        from swarmloc.runner.inprocess import truth_table
        from swarmloc.runner.result import RobotTrack

        out = {}
        beliefs = self.delayed if delayed else self.beliefs
        for r in sorted({k[0] for k in beliefs}):
            bs = sorted((b for k, b in beliefs.items() if k[0] == r), key=lambda b: b.stamp)
            times = np.array([b.stamp for b in bs])
            if bs and bs[0].group == "SE3":  # an SE(3) team: (x, y, z, qx, qy, qz, qw) and 6 x 6, as in-process
                means = pose7(np.array([b.mean for b in bs]).reshape(-1, 4, 4)).reshape(-1, 7)
                covs = np.array([b.cov for b in bs]).reshape(-1, 6, 6)
            else:
                means = SE2.to_xytheta(np.array([b.mean for b in bs]).reshape(-1, 3, 3)).reshape(-1, 3)
                covs = np.array([b.cov for b in bs]).reshape(-1, 3, 3)
            w = means.shape[-1]
            tr = truth_table(truth, r, times) if times.size else np.full((0, w), np.nan)  # NaN where truth is not
            out[r] = RobotTrack(times, means, covs, tr if tr.shape == (times.size, w) else np.full_like(means, np.nan))
        return out


def _python() -> list[str]:
    return [sys.executable, "-m", "swarmloc.cli"]


def launch_team(
    *,
    src: Source,
    source: str | None = None,
    robots: int = 3,
    estimator: str = "expfusion",
    duration: float | None = None,
    seed: int = 0,
    config_file: str | None = None,
    server: bool = False,
    faults: str | None = None,
    speed: float = 0.0,
    lag: float = 0.5,
    association: str = "tags",
    team: str | None = None,
    max_wall: float = 600.0,
    ros_domain: int | None = None,
    log_dir: str | os.PathLike[str] | None = None,
    verbose: bool = False,
    connect_extra: Sequence[str] = (),
    keys_dir: str | os.PathLike[str] | None = None,
    view: Any = None,
    progress: Callable[[int, int], None] | None = None,
    routers: int = 0,
    **waits: Unpack[Waits],
) -> TeamRun:
    """Start the team of ``src`` on 127.0.0.1, collect its beliefs and reports, stop every process.

    Each node process loads the source itself from ``source`` (its spec; default ``src.spec``), ``robots``,
    ``duration``, ``seed`` and ``config_file``, as ``swarmloc node`` does; ``robots`` applies to simulated sources
    (a dataset's robots are its own). Faults: :mod:`swarmloc.net.faults`; a kill fault needs the belief server
    (started automatically). ``waits``: every node's timeouts [s] and ``answer_retries``
    (:class:`~swarmloc.net.timeouts.Waits`);
    ``max_wall`` [s] is the whole run's wall-clock limit. ``connect_extra``: endpoints every process also connects
    to (a Zenoh router, e.g. ROS 2's ``rmw_zenohd`` on ``tcp/127.0.0.1:7447``). ``keys_dir``: the team's keys and
    roster (:class:`~swarmloc.net.auth.TeamKeys`: made there unless its ``roster.json`` exists; default: a temporary
    folder, removed at the end). ``view``: a :class:`~swarmloc.net.view.TeamView` shown every belief and line
    collected (the caller closes it). ``progress(collected, expected)``: called as beliefs come in (a count of the
    beliefs collected and of those the run records: record times x robots). ``routers``: 0, every process a Zenoh
    peer of the others; ``n >= 1``, ``n`` meshed Zenoh routers on 127.0.0.1 started here and every process a client
    of one of them, in turn (:func:`~swarmloc.net.transport.router_mesh`), the routers meshed with ``connect_extra``.
    """
    f = parse_faults(faults)
    NetSettings(speed=speed, lag=lag, faults=f, ros_domain=ros_domain, **waits)  # what every node would refuse
    team = check_team(team or f"team{os.getpid()}")
    network_class(estimator)  # refuse an estimator a team cannot run before starting anything
    hosted = hosted_class(estimator) is not None
    if hosted and (f.kill is not None or f.late is not None):
        raise ValueError(f"faults: kill and late are for a distributed team; {estimator!r} is hosted by the server")
    server = server or hosted or (f.kill is not None and f.restart)
    for what, robot in (("late", f.late), ("killed", f.kill)):
        if robot is not None and robot[0] not in src.robots:
            raise ValueError(f"faults: {what} robot {robot[0]} is not in the team {src.robots}")
    if f.joiner is not None and speed == 0:
        log.warning("team: robot %d's process starts during the run (--faults %s), but at --speed 0 the team may read "
                    "its sources before it is up: it then runs alone and exits 3 (--speed 1: in real time)",
                    f.joiner, f.to_spec())  # fmt: skip
    node_args = node_arguments(
        source=src.spec if source is None else source, estimator=estimator, robots=robots, duration=duration,
        seed=seed, config_file=config_file, speed=speed, lag=lag, use_server=server, faults=f,
        ros_domain=ros_domain, verbose=verbose, association=association, **waits,
    )  # fmt: skip
    server_args = server_arguments(node_args) if hosted else []
    keys = TeamKeys(src.robots, keys_dir)
    try:
        mesh: AbstractContextManager[list[str]] = router_mesh(routers, connect_extra) if routers else nullcontext([])
        with mesh as relays:
            launcher = _Launcher(team, src.robots, node_args, f, server, connect_extra, log_dir, keys,
                                 src.record_times(), pose_stamps(src), relays)  # fmt: skip
            launcher.server_args = server_args
            launcher.view = view
            launcher.on_progress = progress
            return launcher.run(src.t_start, max_wall)
    finally:
        keys.close()


def pose_stamps(src: Source) -> frozenset[float]:
    """The stamps a smoother's window can hold a pose at, so its delayed output's: the source's start and every
    detection instant (a pose per group; ``flsd``'s also at its teammates')."""
    out = {float(e.stamp) for e in src.events if isinstance(e, Detection) and isinstance(e.stamp, int | float)}
    return frozenset({float(src.t_start), *out})


def node_arguments(
    *,
    source: str,
    estimator: str,
    robots: int,
    duration: float | None,
    seed: int,
    config_file: str | None,
    speed: float,
    lag: float,
    use_server: bool,
    faults: Faults,
    ros_domain: int | None,
    verbose: bool,
    association: str = "tags",
    **waits: Unpack[Waits],
) -> list[str]:
    """The ``swarmloc node`` options every node process of a team gets (the link faults only; a node's own
    ``--robot``, ``--wait-for``, endpoints and ``--resume`` are the launcher's); each of ``waits`` left out: its
    default."""
    out = ["--source", source, "--estimator", estimator, "--robots", str(robots), "--seed", str(seed),
           "--speed", str(speed), "--lag", str(lag)]  # fmt: skip
    for name, (default, _) in TIMEOUTS.items():
        out += ["--" + name.replace("_", "-"), str(waits.get(name, default))]
    out += ["--answer-retries", str(waits.get("answer_retries", ANSWER_RETRIES))]
    if duration is not None:
        out += ["--duration", str(duration)]
    if config_file:
        out += ["--config", str(config_file)]
    if association != "tags":  # the ids hidden in every process alike (swarmloc.experiments.association)
        out += ["--association", association]
    if use_server:
        out.append("--use-server")
    f = faults
    if f.link or f.jump is not None:
        out += ["--faults", f.node_faults().to_spec()]
    if ros_domain is not None:
        out += ["--ros-domain", str(ros_domain)]
    if verbose:
        out.append("--verbose")
    return out


def server_arguments(node_args: Sequence[str]) -> list[str]:
    """The options of ``swarmloc server`` that host the team's estimator, taken from the nodes' (the source, the
    estimator, and the waits for the robots)."""
    keep = ("--source", "--estimator", "--seed", "--duration", "--config", "--start-timeout", "--lost-timeout",
            "--association")  # fmt: skip
    return [x for i, a in enumerate(node_args) if a in keep for x in node_args[i : i + 2]]


class _Launcher:
    """The processes of one team run: their endpoints and command lines, starting and stopping them, the process
    faults (kill and restart, late join), and the collection of what they publish."""

    def __init__(
        self,
        team: str,
        robots: list[int],
        node_args: list[str],
        faults: Faults,
        server: bool,
        connect_extra: Sequence[str],
        log_dir: str | os.PathLike[str] | None,
        keys: TeamKeys,
        record_times: Iterable[float],
        pose_stamps: frozenset[float] = frozenset(),
        routers: Sequence[str] = (),
    ) -> None:
        self.team, self.robots, self.node_args, self.f, self.server = team, robots, node_args, faults, server
        self.run_id = secrets.token_hex(6)  # in every key with the team's name: two teams of one name never meet
        self.scope = team_scope(team, self.run_id)
        self.roster = frozenset(robots)
        self.keys, self.auth = keys, keys.auth(COLLECTOR)
        self.record_times = frozenset(float(t) for t in record_times)
        self.pose_stamps = pose_stamps  # where a delayed pose may be stamped (:func:`pose_stamps`)
        names = [f"robot{r}" for r in robots] + (["server"] if server else [])
        ports = dict(zip([*names, "collector"], free_ports(len(names) + 1), strict=True))
        self.ep = {k: f"tcp/127.0.0.1:{p}" for k, p in ports.items()}
        self.connect_extra = list(connect_extra)  # e.g. a Zenoh router (ROS 2)
        self.routers = list(routers)  # the team's Zenoh routers; none: the processes are peers of one another
        self.late = faults.late[0] if faults.late is not None else None
        self.wait_for = [r for r in robots if r != self.late]
        # each process's output goes to <logs>/<name>.log; without log_dir, to a temporary folder removed at the end,
        # kept long enough to say why a process that failed did
        self._temp_logs = log_dir is None
        self.logs = Path(tempfile.mkdtemp(prefix="swarmloc-team-logs-") if log_dir is None else log_dir)
        self.logs.mkdir(parents=True, exist_ok=True)
        self.procs: dict[str, subprocess.Popen] = {}
        self.result = TeamRun(run_id=self.run_id)
        self._refuse = Refusals(self.result.counts, self.result.reasons, "collector", log, verb="refused",
                                prefix="collector_", warn=math.inf)  # fmt: skip
        self.progress: dict[int, float] = {}
        self._intake = self.inq = Intake(self.roster | {SERVER}, COLLECTOR_BUDGET, signed=True,
                                         vouch=vouch_for(self.auth))  # fmt: skip
        self.killed = self.restarted = self.joined = False
        self.deadline = math.inf  # the run's end (monotonic), set when it starts
        self.noted: set[int] = set()  # pids of the processes in ``result.ended``
        self.server_args: list[str] = []  # a hosted estimator's options for ``swarmloc server``
        self.view: Any = None  # a live view (swarmloc.net.view.TeamView) shown what is collected
        self.on_progress: Callable[[int, int], None] | None = None  # (beliefs collected, beliefs of the run)
        self._shown = -1

    # ------------------------------------------------------------------------------------------- processes
    def args_for(self, name: str, extra: Sequence[str] = ()) -> list[str]:
        """The network options of process ``name``: its endpoint and the others' (peers), or its router (a client)."""
        if self.routers:
            where = ["--zenoh-config", str(self.client_file(name))]
        else:
            others = [self.ep[k] for k in self.ep if k != name] + self.connect_extra
            where = ["--listen", self.ep[name], "--connect", ",".join(others)]
        return ["--team", self.team, "--run-id", self.run_id, *where, "--parent-pid", str(os.getpid()), *extra]

    def client_file(self, name: str) -> Path:
        """The Zenoh configuration that makes process ``name`` a client of one of the routers (in turn by name)."""
        path = self.logs / f"zenoh-{name}.json5"
        if not path.exists():
            router = self.routers[list(self.ep).index(name) % len(self.routers)]
            path.write_text(json.dumps(client_config([router]), indent=1))
        return path

    def spawn(self, name: str, cmd: list[str]) -> None:
        with open(self.logs / f"{name}.log", "ab") as out:
            self.procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)

    def last_words(self, name: str, lines: int = 3, limit: int = 600) -> str:
        """The last ``lines`` non-empty lines a process wrote (at most ``limit`` characters), or ''."""
        try:
            with open(self.logs / f"{name}.log", "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(0, f.tell() - 8192))
                text = f.read().decode("utf-8", "replace")
        except OSError:
            return ""
        return " | ".join([ln.strip() for ln in text.splitlines() if ln.strip()][-lines:])[-limit:]

    def left(self) -> list[str]:
        """``--max-wall`` with what is left of the run's time: a process bounds itself even without its launcher."""
        return ["--max-wall", f"{max(1.0, self.deadline - time.monotonic()):.1f}"]

    def node_cmd(self, r: int, resume: bool = False) -> list[str]:
        # a restarted or late robot joins a running team: it waits for nobody
        wait = "none" if resume or r == self.late else ",".join(map(str, self.wait_for)) or "none"
        extra = [*self.node_args, "--robot", str(r), "--wait-for", wait, *self.keys.args(r), *self.left()]
        return [*_python(), "node", *self.args_for(f"robot{r}", extra), *(["--resume"] if resume else [])]

    def start(self) -> None:
        if self.server:
            roster = ",".join(map(str, self.robots))
            keys = [*self.keys.args(SERVER), *self.server_args, *self.left()]
            self.spawn("server", [*_python(), "server", *self.args_for("server", keys), "--robots", roster])
        for r in self.robots:
            if r != self.late:
                self.spawn(f"robot{r}", self.node_cmd(r))

    def apply_faults(self, t_first: float) -> None:
        """Start the late robot once the others have read far enough (or are all gone); kill a robot once it has
        read far enough, and restart it (``--resume``)."""
        f, procs, counts = self.f, self.procs, self.result.counts
        if f.late is not None and not self.joined:
            others = [self.progress.get(r, -math.inf) for r in self.wait_for]
            # join once the others have read that far, or once they are all gone (a join time past the end)
            gone = all(procs[f"robot{r}"].poll() is not None for r in self.wait_for)
            if (others and min(others) >= t_first + f.late[1]) or gone:
                self.spawn(f"robot{f.late[0]}", self.node_cmd(f.late[0]))
                self.joined = True
                counts["late_joined"] = 1
        if f.kill is not None and not self.killed:
            k, tk = f.kill
            if self.progress.get(k, -math.inf) >= t_first + tk:
                procs[f"robot{k}"].kill()
                reap(procs[f"robot{k}"])
                how = f"killed by the fault kill={k}@{tk:g}, restarted" if f.restart else \
                    f"killed by the fault killonly={k}@{tk:g}, not restarted"  # fmt: skip
                self.note(f"robot{k}", procs[f"robot{k}"], how)
                self.killed = True
                counts["killed"] = 1
        if self.killed and not self.restarted and f.restart and f.kill is not None:  # killed: by f.kill
            time.sleep(0.5)
            self.spawn(f"robot{f.kill[0]}", self.node_cmd(f.kill[0], resume=True))
            self.restarted = True
            counts["restarted"] = 1

    def note(self, name: str, p: subprocess.Popen, how: str = "") -> None:
        """Record (once) and log a process that ended with a non-zero exit code: how, or by which signal."""
        rc = p.returncode
        if rc in (None, 0) or p.pid in self.noted:
            return
        self.noted.add(p.pid)
        how = how or (f"died ({signal.Signals(-rc).name})" if -rc in signal.valid_signals() else "exited with an error")
        said = self.last_words(name) if rc > 0 else ""
        self.result.ended.append({"process": name, "pid": p.pid, "exit_code": rc, "how": how, "said": said})
        log.warning("team: %s (pid %d) %s, exit code %d%s", name, p.pid, how, rc, f": {said}" if said else "")

    def note_ended(self, how: str = "") -> None:
        """Record every process that has ended with a non-zero exit code since the last look."""
        for name, p in self.procs.items():
            if p.poll() is not None:
                self.note(name, p, how)

    def all_ended(self) -> bool:
        """Every robot's process was started (the late one, the restarted one) and has ended."""
        nodes = [p for n, p in self.procs.items() if n.startswith("robot")]
        joined = self.late is None or self.joined
        started = joined and (self.f.kill is None or self.restarted or self.killed is False or not self.f.restart)
        return started and all(p.poll() is not None for p in nodes) and len(nodes) == len(self.robots)

    # ------------------------------------------------------------------------------------------- collecting
    def collect(self, sample: Any) -> None:
        """Keep a published belief, report or progress announcement signed by the robot whose key it is published on,
        or a belief or report signed by the server on its own keys (a hosted estimator's; a bad payload, or a belief
        stamped at no record time of the run, is counted and dropped)."""
        try:
            key = str(sample.key_expr)
            on_server = key in (server_key(self.scope, "belief"), server_key(self.scope, "report"))
            env = open_envelope(self.auth, key, sample.payload.to_bytes(), self.team, self.roster, server_ok=on_server,
                                publication=not on_server)  # fmt: skip
            if on_server and env.from_robot != SERVER:
                raise Rejected(f"robot {env.from_robot} published on the server's key")
            b = env.body
            delayed = key.endswith("/delayed")
            if delayed and not (isinstance(b, Belief) and b.stamp in self.pose_stamps and b.group == "SE2"):
                raise Rejected("delayed output that is no SE(2) belief at a detection instant of the run")
            if isinstance(b, Belief) and not delayed and b.stamp not in self.record_times:
                raise Rejected("belief stamped at no record time of the run")
        except Rejected as exc:
            self._refuse(exc.reason, "message", exc)
            return
        if self.view is not None and not delayed:
            self.view.observe(b)
        if isinstance(b, Belief) and delayed:
            self.result.keep(b, delayed=True)
            self.result.counts["delayed_collected"] += 1
        elif isinstance(b, Belief):
            self.result.keep(b)
        elif isinstance(b, Report):
            self.result.reports[b.robot] = b
        elif isinstance(b, Lines):
            self.result.lines.append(b)
        elif isinstance(b, Progress) and math.isfinite(b.t):
            self.progress[b.robot] = max(self.progress.get(b.robot, -math.inf), b.t)

    def watch(self, t_first: float, max_wall: float, t0: float) -> None:
        """Collect and apply the faults until every node has ended (then collect what is still queued, for at most
        ``COLLECT_AFTER_END`` s) or the run has taken ``max_wall`` s: nothing that keeps coming holds it longer."""
        deadline = t0 + max_wall
        while True:
            if time.monotonic() > deadline:
                self.result.counts["timed_out"] = 1
                log.warning("team: time limit of %.0f s reached; stopping every process", max_wall)
                return
            with suppress(queue.Empty):
                self.collect(self.inq.get(timeout=0.1)[1])
            self._intake.fold(self.result.counts, self.result.reasons, prefix="collector_")
            self.apply_faults(t_first)
            self.note_ended()
            if self.on_progress is not None and len(self.result.beliefs) != self._shown:
                self._shown = len(self.result.beliefs)
                self.on_progress(self._shown, len(self.record_times) * len(self.robots))
            if self.all_ended():
                end = min(deadline, time.monotonic() + COLLECT_AFTER_END)
                while (left := end - time.monotonic()) > 0:  # what is still queued
                    try:
                        self.collect(self.inq.get(timeout=min(0.3, left))[1])
                    except queue.Empty:
                        return
                return

    def _map_refused(self, reason: str) -> None:
        self.result.reasons[f"map answer: {reason}"] += 1

    def ask_map(self, session: Any, timeout: float = 5.0) -> MapAnswer | None:
        """The belief server's map (signed by the server), once it has every :class:`Lines` collected: asked again
        until ``timeout`` s have passed (then the last answer, or None)."""
        want, last, end = len(self.result.lines), None, time.monotonic() + timeout
        while time.monotonic() < end:
            answers = list(map_answers(session, self.scope, self.team, self.roster, self.auth, self._map_refused))
            last = answers[-1] if answers else last
            if last is not None and last.messages >= want:
                return last
            time.sleep(0.1)
        self.result.counts["map_incomplete"] = 1
        return last

    def run(self, t_first: float, max_wall: float) -> TeamRun:
        """Start the team, watch it, and stop every process it started, whatever happens (``t_first``: the
        source's start, which the fault times count from)."""
        if self.routers:
            session = open_session(config_file=self.client_file("collector"))
        else:
            others = [self.ep[k] for k in self.ep if k != "collector"] + self.connect_extra
            session = open_session([self.ep["collector"]], others)
        presence = Presence(session, self.scope, self.auth)
        presence.join()  # the nodes make their sessions with it as they start
        put = self.inq.offer  # within the collector's budgets (:mod:`swarmloc.net.intake`)
        presence.decl += [
            session.declare_subscriber(robot_key(self.scope, "*", what), handler=lambda x: put(("sample", x)))
            for what in ("belief", "report", "progress", "lines", "delayed")
        ] + [session.declare_subscriber(server_key(self.scope, w), handler=lambda x: put(("sample", x)))
             for w in ("belief", "report")]  # fmt: skip
        t0 = time.monotonic()
        self.deadline = t0 + max_wall
        try:
            self.start()
            self.watch(t_first, max_wall, t0)
            if self.server and not self.result.counts["timed_out"]:
                self.result.map = self.ask_map(session)
        finally:
            presence.undeclare()
            self._intake.fold(self.result.counts, self.result.reasons, prefix="collector_")
            self.note_ended()  # those that ended by themselves, then those the launcher stops
            stop_all(self.procs)
            limit = " at its time limit" if self.result.counts["timed_out"] else ""
            self.note_ended(f"stopped by the launcher{limit}")
            self.result.exit_codes = {n: p.returncode for n, p in self.procs.items()}
            presence.leave(counts=self.result.counts, prefix="collector_")
            session.close()
            if self._temp_logs:
                shutil.rmtree(self.logs, ignore_errors=True)
            self.result.wall_s = time.monotonic() - t0
        return self.result


def stop_all(procs: dict[str, subprocess.Popen] | Iterable[subprocess.Popen], grace: float = 3.0) -> None:
    """SIGTERM every process still running (its whole session: start them with ``start_new_session=True``), then
    SIGKILL what is left after ``grace`` s; reap them all."""
    procs = list(procs.values()) if isinstance(procs, dict) else list(procs)
    for p in procs:
        if p.poll() is None:
            with suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
    end = time.monotonic() + grace
    for p in procs:
        try:
            p.wait(timeout=max(0.0, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            with suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
            reap(p)


def reap(p: subprocess.Popen, timeout: float = 5.0) -> None:
    """Wait at most ``timeout`` s for process ``p``, SIGKILLed, to end (one stuck in the kernel may outlive its kill
    for a while: it is logged and left, never waited for without bound)."""
    try:
        p.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        log.warning("team: process %d still running %.0f s after SIGKILL; not waiting for it", p.pid, timeout)
