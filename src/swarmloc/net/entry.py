"""``swarmloc node`` and ``swarmloc server``: the entry points of one robot's process and of the belief server's.

:func:`node_main` runs one robot (its own events of a :class:`~swarmloc.datasets.source.Source`, one node of a
distributed estimator) on a Zenoh peer until the team is done; :func:`server_main` runs the belief server. The
caller builds the source (``swarmloc node`` loads it by its spec): a node process reads only its own robot's
events of it, never the ground truth. With ``auth`` (:class:`~swarmloc.net.auth.Auth`: the process's key and the
team's roster, ``swarmloc node --key FILE --roster FILE``) everything sent is signed and everything received
authenticated (:mod:`swarmloc.net.auth`).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from collections.abc import Callable, Container, Iterator, Sequence
from contextlib import suppress
from pathlib import Path
from typing import Any, Unpack

import numpy as np

from swarmloc.config import Config
from swarmloc.datasets.source import Source
from swarmloc.events import Event, Odometry, OwnEvent
from swarmloc.net.auth import Auth, open_envelope
from swarmloc.net.faults import Faults, parse_faults
from swarmloc.net.schema import SERVER, Belief, MapAnswer, Rejected, Report
from swarmloc.net.teamlink import TeamLink
from swarmloc.net.timeouts import LOST_TIMEOUT, START_TIMEOUT, Waits
from swarmloc.net.transport import open_session, server_key, team_scope

log = logging.getLogger(__name__)

RESUME_TIMEOUT = 5.0
"""[s] wall time a restarted node (``resume``) waits for its own latest belief from the belief server."""


def hosted_class(estimator: str) -> type | None:
    """The node class of a centralized ``estimator`` the belief server can host (``cekf``, ``iekf``, ``fej``: one
    node for the team, fed by the robots' forwarded measurements, :mod:`swarmloc.net.central`); None for another
    known one; ValueError naming the choices for an unknown one."""
    from swarmloc.estimators import estimator_class

    cls = estimator_class(estimator)
    return None if cls.distributed else cls


def network_class(estimator: str) -> type:
    """The node class of an estimator a networked team can run: distributed (one node per robot process) or
    centralized, hosted by the server (:func:`hosted_class`); ValueError naming the choices else."""
    return hosted_class(estimator) or distributed_class(estimator)


def distributed_class(estimator: str, initial: Any = None) -> type:
    """The node class of a distributed ``estimator`` (one node per robot) for a robot with this ``initial`` belief
    (an SE(3) one picks from :data:`~swarmloc.estimators.ESTIMATORS_SE3`); ValueError naming the choices else."""
    from swarmloc.estimators import ESTIMATORS, ESTIMATORS_SE3, estimator_class
    from swarmloc.lie import SE3
    from swarmloc.node import RobotNode

    se3 = getattr(initial, "group", None) is SE3
    table = ESTIMATORS_SE3 if se3 else ESTIMATORS  # a 3-D team's table
    cls = estimator_class(estimator, {0: initial} if se3 else None)  # an unknown name, or one without an SE(3) form
    networked = [k for k, c in table.items() if issubclass(c, RobotNode) and c.distributed and c.over_network]
    if not issubclass(cls, RobotNode) or not cls.distributed:
        hosted = sorted(k for k, c in table.items() if not c.distributed)
        raise ValueError(
            f"{estimator!r} is not a distributed estimator (one node per robot): run it in-process with "
            f"'swarmloc evaluate', or hosted by the belief server ('swarmloc server --estimator', 'swarmloc team "
            f"--estimator'; centralized: {hosted}); one node per robot process: choose from {networked}"
        )
    if not cls.over_network:
        raise ValueError(
            f"{estimator!r} needs a broadcast to every teammate per update, which the network driver does not carry "
            f"yet: run it in-process with 'swarmloc evaluate'; over the network choose from {networked}"
        )
    return cls


def make_node(
    estimator: str,
    robot: int,
    initial: Any,
    config: Config,
    landmarks: Any,
    team: Sequence[int] = (),
    noise: Any = None,
) -> Any:
    """The node of ``robot`` for a distributed ``estimator`` with the options ``swarmloc evaluate`` uses; ``team``:
    every robot id of the team, for an estimator that keeps the whole team's correlations (``diekf``; default:
    ``robot`` alone); ``noise``: the source's process noise when it is not ``config.motion``'s (an SE(3) team's
    :class:`~swarmloc.motion.twist3.TwistNoise`). The class follows the initial belief's group."""
    from swarmloc.estimators import accepted_options, node_options

    cls = distributed_class(estimator, initial)
    options = node_options(estimator, config, landmarks)
    if noise is not None:
        options["noise"] = noise
    options = {k: v for k, v in options.items() if k in accepted_options(cls)}
    if "team" in accepted_options(cls):
        options["team"] = tuple(team) or (robot,)
    return cls(robot, initial, **options)


def resume_events(events: Sequence[OwnEvent], t: float) -> list[OwnEvent]:
    """A robot's events from ``t`` on: the command in force at ``t`` clipped to start there, later ones as they are."""
    out: list[OwnEvent] = []
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
    src: Source,
    robot: int,
    team: str,
    estimator: str,
    speed: float = 0.0,
    lag: float = 0.5,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    zenoh_config: str | None = None,
    use_server: bool = False,
    resume: bool = False,
    faults: str | Faults | None = None,
    wait_for: Sequence[int] | None = None,
    ros_domain: int | None = None,
    max_wall: float | None = None,
    out: str | os.PathLike[str] | None = None,
    auth: Auth | None = None,
    run_id: str | None = None,
    live: Any = None,
    view: Any = None,
    **waits: Unpack[Waits],
) -> Report:
    """Run robot ``robot`` of ``src`` as one Zenoh peer until the team is done; returns its report. With
    ``out``: also write ``robot<N>.tum`` (its final beliefs) and ``robot<N>.json`` (its report) there.

    ``waits``: the timeouts [s] and ``answer_retries`` of :class:`~swarmloc.net.process.NetNode`
    (:class:`~swarmloc.net.timeouts.Waits`); ``max_wall`` [s] stops the node whatever its state (None: no limit).
    ``auth``: robot ``robot``'s key and the team's roster (None: unauthenticated);
    ``run_id``: the run's id in every key (:func:`~swarmloc.net.transport.team_scope`). ``live``: read the robot's
    inputs live, not ``src``'s events: ``live(session, robot, t0) -> (feed, close)``
    (:func:`swarmloc.live.source.live_inputs`; ``src`` still gives the team, initial beliefs and record times).
    ``view``: a :class:`~swarmloc.net.view.TeamView` shown this robot's beliefs and lines, and the belief server's
    map, asked for every second while the node runs and once at its end (not with a server-hosted estimator)."""
    from swarmloc.net.lockstep import detected_pairs
    from swarmloc.net.process import NetNode
    from swarmloc.net.settings import NetSettings

    scope = team_scope(team, run_id)
    if robot not in src.initial:
        raise ValueError(f"robot {robot} is not in source {src.spec!r} (robots {src.robots})")
    _check_roster(auth, src.robots)
    if hosted_class(estimator) is not None:
        if live is not None:
            raise ValueError(f"a live source needs a distributed estimator, not the server-hosted {estimator!r}")
        if resume or use_server:
            log.info("robot %s: --resume and --use-server do not apply to a server-hosted estimator", robot)
        return _forward(src, robot, team, listen, connect, zenoh_config, faults, speed,
                        waits.get("start_timeout", START_TIMEOUT), waits.get("lost_timeout", LOST_TIMEOUT), max_wall,
                        out, auth, run_id)  # fmt: skip
    session = open_session(listen, connect, zenoh_config)
    finals: dict[float, Belief] = {}
    close_live = None
    try:
        node, events, record_times = _start(session, src, robot, team, estimator, resume, auth, scope)
        if live is None:
            node.plan(src.events)  # a recording: known in advance (diekf's re-forming clusters)
        faults = parse_faults(faults) if isinstance(faults, str | None) else faults
        events, close_live = _inputs(live, session, robot, node, events, faults, resume)
        settings = NetSettings(run_id=run_id, speed=speed, lag=lag, use_server=use_server, faults=faults,
                               wait_for=None if wait_for is None else frozenset(wait_for), ros_domain=ros_domain,
                               **waits)  # fmt: skip
        net = NetNode(node, events, session=session, team=team, roster=src.robots, record_times=record_times,
                      settings=settings, on_belief=lambda b: _on_belief(b, finals, view),
                      on_lines=None if view is None else view.observe, auth=auth,
                      scans=None if live is not None else _own_scans(src, robot, events),
                      detected=None if live is not None else detected_pairs(src.events))  # fmt: skip
        _stop_on_sigterm(net.stop)
        report = _run_viewed(net, max_wall, view, session, scope, team, src.robots, auth)
        if out is not None:
            _write_outputs(Path(out), robot, [finals[t] for t in sorted(finals)], report)
        return report
    finally:
        if close_live is not None:
            close_live()
        session.close()


def _run_viewed(net: Any, max_wall: float | None, view: Any, session: Any, scope: str, team: str,
                roster: Sequence[int], auth: Auth | None) -> Report:  # fmt: skip
    """``net.run(max_wall=...)``, with the belief server's map polled for ``view`` meanwhile (``session`` to
    ``auth``: :class:`_MapPoller`'s arguments before ``view``) and once at the end."""
    poller = None if view is None else _MapPoller(session, scope, team, roster, auth, view)
    try:
        return net.run(max_wall=max_wall)
    finally:
        if poller is not None:
            poller.finish()


def _on_belief(b: Belief, finals: dict[float, Belief], view: Any) -> None:
    if b.final:
        finals[b.stamp] = b
    if view is not None:
        view.observe(b)


def server_replies(session: Any, selector: str, team: str, roster: Container[int], auth: Auth | None,
                   refused: Callable[[str], object]) -> Iterator[Any]:  # fmt: skip
    """The bodies of the belief server's replies to one query of ``session`` on ``selector`` (its query key with
    parameters), as they come: those the server sent (signed, with ``auth``); ``refused(reason)`` for each reply
    refused."""
    import zenoh

    for reply in session.get(
        selector, timeout=1.0, target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE
    ):
        if reply.ok is None:
            continue
        try:
            env = open_envelope(auth, str(reply.ok.key_expr), reply.ok.payload.to_bytes(), team, roster)
        except Rejected as exc:
            refused(exc.reason)
            continue
        if env.from_robot == SERVER:
            yield env.body


def map_answers(session: Any, scope: str, team: str, roster: Container[int], auth: Auth | None,
                refused: Callable[[str], object]) -> Iterator[MapAnswer]:  # fmt: skip
    """The belief server's answers to one ``?map`` query of ``session`` in ``scope``, as they come: those the server
    sent (signed, with ``auth``); ``refused(reason)`` for each reply refused."""
    for body in server_replies(session, f"{server_key(scope)}?map", team, roster, auth, refused):
        if isinstance(body, MapAnswer):
            yield body


class _MapPoller(threading.Thread):
    """Asks the belief server for its map every ``every`` s [wall] and shows each answer (signed by the server when
    ``auth``) in ``view``; :meth:`finish` asks once more (the lines of the node's end) and stops it."""

    def __init__(self, session: Any, scope: str, team: str, roster: Sequence[int], auth: Auth | None, view: Any,
                 every: float = 1.0) -> None:  # fmt: skip
        super().__init__(daemon=True, name="map poller")
        self.session, self.scope, self.team, self.roster, self.auth = session, scope, team, roster, auth
        self.view, self.every = view, every
        self.stopped = threading.Event()
        self.answers = 0
        self.start()

    def ask(self) -> None:
        try:
            answers = list(map_answers(self.session, self.scope, self.team, self.roster, self.auth, self.refused))
        except Exception as exc:  # noqa: BLE001 - a closed session or a network error: the view only misses a map
            log.debug("map poller: %s", exc)
            return
        for answer in answers:
            self.view.show_map(answer)
            self.answers += 1

    @staticmethod
    def refused(reason: str) -> None:
        log.warning("map poller: refused a reply: %s", reason)

    def run(self) -> None:
        while not self.stopped.wait(self.every):
            self.ask()

    def finish(self) -> None:
        self.stopped.set()
        self.join()
        self.ask()


def _inputs(live: Any, session: Any, robot: int, node: Any, events: Any, faults: Faults, resume: bool) -> tuple:
    """``(what the node reads, closer or None)``: the live feed (``live``), or the source's events with the jump
    fault (this robot's clock, not the source, is wrong)."""
    if live is None:
        return faults.jumped(robot, events), None
    if resume:
        raise ValueError("a live source cannot resume from the belief server")
    return live(session, robot, float(node.t0))


def _forward(
    src: Source, robot: int, team: str, listen: Sequence[str], connect: Sequence[str], zenoh_config: str | None,
    faults: str | Faults | None, speed: float, start_timeout: float, lost_timeout: float, max_wall: float | None,
    out: str | os.PathLike[str] | None, auth: Auth | None, run_id: str | None,
) -> Report:  # fmt: skip
    """Robot ``robot``'s process for a server-hosted estimator: forward its own events (:mod:`.central`)."""
    from swarmloc.net.central import Forwarder

    faults = parse_faults(faults) if isinstance(faults, str | None) else faults
    with open_session(listen, connect, zenoh_config) as session:
        link = TeamLink(session, team, src.robots, auth, run_id)
        fw = Forwarder(robot, faults.jumped(robot, src.own_events(robot)), link, faults=faults, speed=speed,
                       start_timeout=start_timeout, lost_timeout=lost_timeout)  # fmt: skip
        _stop_on_sigterm(fw.stop)
        report = fw.run(max_wall=max_wall)
        if out is not None:
            _write_report(Path(out), robot, report)
        return report


def _own_scans(src: Source, robot: int, events: Sequence[Event]) -> Any:
    """``robot``'s range scans from its first event on (a resumed node's earlier ones were sent before), or None."""
    if src.scans is None or robot not in src.scans:
        return None
    from swarmloc.mapping import ScanSeries

    sc = src.scans[robot]
    stamps = [e.stamp for e in events]
    keep = sc.times >= (min(stamps) if stamps else src.t_start)
    return ScanSeries(sc.times[keep], sc.ranges[keep], sc.angles, sc.sigma)


def _check_roster(auth: Auth | None, robots: Sequence[int]) -> None:
    """The team's roster must name every robot of the source (a robot left out could not be heard)."""
    if auth is not None:
        missing = sorted(set(robots) - set(auth.roster.robots))
        if missing:
            raise ValueError(f"the roster has no key for robots {missing} of the team {list(robots)}")


def _start(
    session: Any, src: Source, robot: int, team: str, estimator: str, resume: bool, auth: Any, scope: str
) -> tuple:
    """The started node of ``robot``, the events it reads and its record times: from the source's start, or with
    ``resume`` from its latest belief on the team's belief server."""
    from swarmloc.gaussian import GroupGaussian
    from swarmloc.lie import SE2

    events = src.own_events(robot)
    initial = src.initial[robot]
    record_times = src.record_times()
    if resume:
        if initial.group.dim != 3:
            raise ValueError("resume is for SE(2) teams: an SE(3) team starts from its source's initial beliefs")
        from swarmloc.net.pairing import attach

        attach(auth, session, scope, hello=False)  # the server's reply is opened in session with it
        b = _latest_from_server(session, team, src.robots, robot, auth, scope)
        initial = GroupGaussian(SE2, np.reshape(b.mean, (3, 3)), np.reshape(b.cov, (3, 3)))
        events = resume_events(events, b.stamp)
        record_times = record_times[record_times > b.stamp]
        t0 = b.stamp
        log.warning("robot %s: resumed from the server's belief at %.3f s", robot, t0)
    else:
        stamps = [e.stamp for e in events]
        t0 = min(stamps) if stamps else src.t_start
    node = make_node(estimator, robot, initial, src.config, src.landmarks, team=src.robots, noise=src.noise)
    node.start(t0)
    return node, events, record_times


def _write_outputs(folder: Path, robot: int, finals: list[Belief], report: Report) -> None:
    """``robot<N>.tum`` (the final beliefs) and ``robot<N>.json`` (the report) in ``folder``."""
    from swarmloc.datasets.tum import write_tum
    from swarmloc.lie import SE2

    _write_report(folder, robot, report)
    if finals and finals[0].group == "SE3":  # full quaternions (swarmloc.datasets.tum.write_tum3)
        from swarmloc.datasets.tum import write_tum3

        poses = np.array([b.mean for b in finals]).reshape(-1, 4, 4)
        write_tum3(folder / f"robot{robot}.tum", np.array([b.stamp for b in finals]), poses)
        return
    xyt = SE2.to_xytheta(np.array([b.mean for b in finals]).reshape(-1, 3, 3)).reshape(-1, 3)
    write_tum(folder / f"robot{robot}.tum", np.array([b.stamp for b in finals]), xyt)


def _write_report(folder: Path, robot: int, report: Report) -> None:
    """``robot<N>.json`` (the report) in ``folder``."""
    import msgspec

    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"robot{robot}.json").write_text(json.dumps(msgspec.to_builtins(report), indent=2))


def _latest_from_server(
    session: Any,
    team: str,
    roster: Sequence[int],
    robot: int,
    auth: Auth | None,
    scope: str,
    timeout: float = RESUME_TIMEOUT,
) -> Belief:
    """``robot``'s latest belief on the team's belief server (its keys under ``scope``), asked for until ``timeout``
    s passed (with ``auth``: only a reply signed by the server)."""

    def refused(reason: str) -> None:
        log.warning("robot %s: refused a reply of the belief server: %s", robot, reason)

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for body in server_replies(session, f"{server_key(scope)}?latest={robot}", team, roster, auth, refused):
            if isinstance(body, Belief) and body.robot == robot:
                return body
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
    auth: Auth | None = None,
    run_id: str | None = None,
    src: Source | None = None,
    estimator: str | None = None,
    start_timeout: float = START_TIMEOUT,
    lost_timeout: float = LOST_TIMEOUT,
    map_out: str | os.PathLike[str] | None = None,
) -> None:
    """Run the belief server of ``team`` (of its run ``run_id``) until SIGTERM / Ctrl-C (or ``max_wall`` s);
    ``auth``: the server's key and the team's roster (None: unauthenticated). With ``estimator`` (centralized:
    ``cekf``, ``iekf``, ``fej``) it hosts that estimator for the team of ``src`` (whose initial beliefs, landmarks,
    configuration and record times it takes; its events come from the robots, :mod:`swarmloc.net.central`);
    ``map_out``: save its fused line map there as GeoJSON when it stops."""
    from swarmloc.net.server import ServerProcess

    team_scope(team, run_id)  # refuse a bad name or run id before opening anything
    _check_roster(auth, roster)
    hosted = None
    if estimator is not None:
        hosted = _hosted(estimator, src, roster, start_timeout, lost_timeout)
    with open_session(listen, connect, zenoh_config) as session:
        sp = ServerProcess(TeamLink(session, team, roster, auth, run_id), hosted=hosted, map_out=map_out)
        _stop_on_sigterm(sp.stop)
        with suppress(KeyboardInterrupt):
            sp.run(max_wall=max_wall)


def _hosted(estimator: str, src: Source | None, roster: Sequence[int], start_timeout: float,
            lost_timeout: float) -> Any:  # fmt: skip
    """The :class:`~swarmloc.net.central.Fusion` of a server-hosted centralized ``estimator`` for ``src``'s team."""
    from swarmloc.estimators import make_team, node_options
    from swarmloc.net.central import Fusion

    if hosted_class(estimator) is None:
        raise ValueError(f"the server hosts a centralized estimator (cekf, iekf, fej), not {estimator!r}: a "
                         "distributed one runs in the robots' processes (swarmloc node)")  # fmt: skip
    if src is None:
        raise ValueError("a hosted estimator needs the team's source (its initial beliefs and configuration)")
    if sorted(roster) != src.robots:
        raise ValueError(f"--robots {sorted(roster)} is not the source's team {src.robots}")
    (node,) = make_team(estimator, src.initial, **node_options(estimator, src.config, src.landmarks))
    return Fusion(node, src.robots, src.record_times(), lost_timeout=lost_timeout, start_timeout=start_timeout)


def _stop_on_sigterm(stop: Any) -> None:
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop())
