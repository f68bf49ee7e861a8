"""Mutual localization from anonymous detections over an event stream (slides 46 and 61: PMR, then the bank).

:func:`track_anonymous` plays one robot (``ego``) of a team whose robots share, at every scan, their anonymous
observations and their odometry (slide 42's communication: packets are signed, the perceptions are not):

* every ``Odometry`` event moves the bank (ego's: :meth:`~ParticleFilterBank.predict_ego`; a neighbour's:
  :meth:`~ParticleFilterBank.predict_neighbour`) by its unicycle increment, applied at the end of its interval;
* at every instant with anonymous detections (:func:`anonymous_scans`), PMR runs on all the robots' scans (a robot
  that saw nothing contributes an empty set), gated by the bank's unambiguous estimates (slide 59); when the gate
  leaves no solution, or leaves a robot unplaced (a kidnapping, a lost filter), PMR runs again without it and those
  robots take their hypotheses from that run; every neighbour's filter is updated with its hypotheses;
* the estimates (:class:`~swarmloc.association.pfbank.BankEstimate`) are recorded after each scan.

The point noise ``sigma`` [m] given to PMR stands for range-bearing noise: ``max(s_r, max_range s_b)`` is the
conservative choice. Anonymous detections are recognized by :func:`is_anonymous_detection` only; ``truth_target``
is never read.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeGuard

import numpy as np

from swarmloc.arrays import readonly
from swarmloc.association.pfbank import BankEstimate, BankSettings, ParticleFilterBank
from swarmloc.association.pmr import multiple_registration
from swarmloc.association.registration import points_from_range_bearing
from swarmloc.events import Detection, Event, Kind, Odometry, sim_order
from swarmloc.gaussian import GroupGaussian, symmetric
from swarmloc.lie import SE2, between_xyt, compose_xyt, wrap_angle
from swarmloc.motion import UnicycleNoise, odometry_increment

__all__ = [
    "AnonymousTrack",
    "anonymous_scans",
    "bank_detections",
    "binned_scans",
    "is_anonymous_detection",
    "lone_detections",
    "track_anonymous",
]


def is_anonymous_detection(e: object) -> TypeGuard[Detection]:
    """An anonymous range-bearing robot detection: ``target=None``, ``target_is_robot``."""
    return isinstance(e, Detection) and e.kind == Kind.RANGE_BEARING and e.target_is_robot and e.target is None


def anonymous_scans(events: Iterable[Event], robots: Sequence[int]) -> dict[float, dict[int, np.ndarray]]:
    """Anonymous detections grouped by time: ``{t: {robot: points (m, 2) in its frame}}`` for every robot in
    ``robots`` (empty arrays for those that saw nothing at ``t``)."""
    out: dict[float, dict[int, list]] = {}
    for e in events:
        if is_anonymous_detection(e):
            out.setdefault(float(e.t), {r: [] for r in robots}).setdefault(e.observer, []).append(e.z)
    return {
        t: {r: points_from_range_bearing(np.array(z)) if z else np.zeros((0, 2)) for r, z in scan.items()}
        for t, scan in out.items()
    }


def binned_scans(
    events: Sequence[Event], robots: Sequence[int], width: float, noise: UnicycleNoise, merge: float = 0.0
) -> dict[float, dict[int, np.ndarray]]:
    """Anonymous detections binned in time, for robots whose detections are stamped each on its own (MRCLAM):
    ``{t_b: {robot: points (m, 2)}}`` with ``t_b`` the end of a bin ``width`` [s] wide (bins counted from the first
    event), every point carried into its observer's frame at ``t_b`` by the observer's own odometry (dead reckoning
    from the detection's stamp to ``t_b``; the robot seen is assumed still over that time, an error of its speed times
    at most ``width``). A robot seen again within a bin (several camera frames) would be two points where PMR
    expects one: a point closer than ``merge`` [m] to a later one of the same observer and bin is dropped."""
    if not (np.isfinite(width) and width > 0):
        raise ValueError(f"binned_scans: width must be a finite number > 0 s, got {width!r}")
    t_first = min(float(e.t) for e in events)
    dr: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for r in robots:  # dead-reckoned pose after each odometry event, from the start
        odo = [e for e in events if isinstance(e, Odometry) and e.robot == r]
        pose = np.zeros(3)
        poses = [pose]
        for o in odo:
            pose = compose_xyt(pose, SE2.to_xytheta(odometry_increment(float(o.v), float(o.w), float(o.dt), noise)[0]))
            poses.append(pose)
        dr[r] = (np.array([float(e.t) for e in odo]), np.array(poses))

    def at(r: int, t: float) -> np.ndarray:
        ts, ps = dr[r]
        return ps[np.searchsorted(ts, t, side="right")]

    out: dict[float, dict[int, list]] = {}
    for e in events:
        if is_anonymous_detection(e):
            tb = t_first + (np.floor((float(e.t) - t_first) / width) + 1) * width
            delta = between_xyt(at(e.observer, float(e.t)), at(e.observer, tb))
            p = points_from_range_bearing(np.asarray(e.z))[0]
            q = between_xyt(delta, np.array([p[0], p[1], 0.0]))[:2]
            pts = out.setdefault(float(tb), {r: [] for r in robots}).setdefault(e.observer, [])
            pts[:] = [x for x in pts if np.hypot(*(x - q)) >= merge] + [q]
    return {
        t: {r: np.array(z).reshape(-1, 2) if z else np.zeros((0, 2)) for r, z in scan.items()}
        for t, scan in sorted(out.items())
    }


@dataclass
class AnonymousTrack:
    """What :func:`track_anonymous` recorded: per scan time, every met robot's estimate and the number of PMR
    solutions; ``counts``: scans, gated and ungated PMR runs, and the bank's counters."""

    times: list[float] = field(default_factory=list)
    estimates: list[dict[int, BankEstimate]] = field(default_factory=list)
    solutions: list[int] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    updates: list[dict[int, str]] = field(default_factory=list)
    """Per scan time: what the bank's update did to each neighbour's filter (:meth:`ParticleFilterBank.update`)."""

    def errors(self, robot: int, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(times, position errors [m], heading errors [rad])`` of ``robot`` against ``truth`` ``(len(times), 3)``
        (its true pose in ego's frame at each recorded time; NaN rows where it was not yet met)."""
        t = np.array(self.times)
        pos, ang = np.full(len(t), np.nan), np.full(len(t), np.nan)
        for k, est in enumerate(self.estimates):
            if robot in est:
                m = SE2.to_xytheta(est[robot].gaussian.mean)
                pos[k] = np.hypot(m[0] - truth[k, 0], m[1] - truth[k, 1])
                ang[k] = abs(wrap_angle(m[2] - truth[k, 2]))
        return t, pos, ang


def _beliefs(bank: ParticleFilterBank) -> dict[int, GroupGaussian]:
    """The bank's unambiguous estimates as beliefs on SE(2), robot id -> belief (PMR's gates)."""
    beliefs = {}
    for j in bank.known():
        est = bank.estimate(j)
        if not est.ambiguous:
            beliefs[j] = GroupGaussian(SE2, est.gaussian.mean, est.gaussian.cov)
    return beliefs


def _hypotheses(
    scan: dict[int, np.ndarray], ego: int, robots: Sequence[int], sigma: float, beliefs: dict[int, GroupGaussian],
    cache: dict | None, counts: dict[str, int], kw: dict[str, Any],
) -> tuple[int, dict[int, list[tuple[np.ndarray, np.ndarray]]]]:  # fmt: skip
    """PMR on one scan, gated by ``beliefs``, and ungated again for the robots (or everything) the beliefs left
    unexplained (kidnapped, or a filter lost): the number of solutions kept and each neighbour's hypotheses;
    counts the runs in ``counts``."""
    res = multiple_registration(scan, ego, sigma, beliefs=beliefs or None, cache=cache, **kw)
    counts["pmr_gated" if beliefs else "pmr_ungated"] += 1
    hyps = {j: res.hypotheses(j) for j in robots if j != ego}
    if beliefs and (not res.solutions or res.unreached):
        free = multiple_registration(scan, ego, sigma, cache=cache, **kw)
        counts["pmr_ungated"] += 1
        for j in hyps:
            if not hyps[j] or not res.solutions:
                hyps[j] = free.hypotheses(j)
        res = res if res.solutions else free
    return len(res.solutions), hyps


def _age(stale: dict[int, int], updates: dict[int, str]) -> None:
    """Scans since PMR last confirmed each filter, after one scan's bank ``updates``: 0 when ``"updated"``, never
    confirmed after an initialization or a reset (drawn from PMR's hypotheses), one more otherwise."""
    for j, u in updates.items():
        if u == "updated":
            stale[j] = 0
        elif u in ("initialized", "reset"):
            stale[j] = 10**9
        else:
            stale[j] = stale.get(j, 10**9) + 1


def _kept(
    bank: ParticleFilterBank, t: float, every: float, fresh: int | None, last: dict[int, float], stale: dict[int, int]
) -> dict[int, BankEstimate]:
    """The estimates a consumer reading every ``every`` s gets at scan ``t`` (:func:`track_anonymous`), noting in
    ``last`` when each was kept."""
    kept = {}
    for j in bank.known():
        if t - last.get(j, -np.inf) < every or (fresh is not None and stale.get(j, 10**9) > fresh):
            continue
        est = bank.estimate(j)
        if not est.ambiguous and np.all(np.linalg.eigvalsh(est.gaussian.cov) > 1e-12):
            kept[j] = est
            last[j] = t
    return kept


def track_anonymous(
    events: Sequence[Event],
    ego: int,
    robots: Sequence[int],
    noise: UnicycleNoise,
    sigma: float,
    *,
    max_range: float = np.inf,
    fov: float = 2 * np.pi,
    max_unmatched: int = 0,
    sigma_range: float | None = None,
    n_particles: int = 500,
    reset_after: int = 6,
    rng: int | None = 0,
    motion_floor: float = 1e-3,
    every: float | None = None,
    registrations: dict[float, dict] | None = None,
    fresh: int | None = None,
    bin_width: float | None = None,
) -> AnonymousTrack:
    """Run PMR and a particle-filter bank for ``ego`` over ``events`` (module docstring). ``noise``: the odometry
    noise model; ``motion_floor`` [m, rad]: std added to every increment (keeps the particles diverse);
    ``reset_after``: the bank's unexplained updates in a row before a filter restarts.

    ``every`` [s]: record only what a consumer of one unambiguous estimate per robot every ``every`` s reads (robot
    ``j``'s estimate is computed at a scan only once ``every`` has passed since the last one kept, and kept only when
    unambiguous with a positive definite covariance); None: every estimate at every scan. ``registrations``: a
    dict shared by the robots of one team over the same events and settings (scan time -> PMR's ``cache``), so that
    each scan's binary registrations are computed once for the team, not once per robot. ``fresh`` (with
    ``every``): keep an estimate only when PMR confirmed its filter (an ``"updated"``, not an initialization or a
    reset) at most ``fresh`` scans before; None: no such condition. ``bin_width`` [s]: PMR on
    :func:`binned_scans` (the detections of each bin carried to its end, processed once the stream passes it) instead
    of the detections that share a stamp."""
    if ego not in robots:
        raise ValueError(f"track_anonymous: ego {ego!r} is not one of the robots {list(robots)}")
    bank = ParticleFilterBank(BankSettings(n_particles=n_particles, reset_after=reset_after), rng=rng)  # it checks them
    if bin_width is None:
        scans = anonymous_scans(events, robots)
    else:
        scans = binned_scans(events, robots, bin_width, noise, merge=sigma)
    pending = sorted(scans) if bin_width is not None else []
    track = AnonymousTrack()
    counts = {"scans": 0, "pmr_gated": 0, "pmr_ungated": 0}
    floor = np.eye(3) * motion_floor**2
    done: set[float] = set()
    last: dict[int, float] = {}
    stale: dict[int, int] = {}  # scans since PMR last confirmed each filter
    kw: dict[str, Any] = dict(max_range=max_range, fov=fov, max_unmatched=max_unmatched, sigma_range=sigma_range)

    def scan(t: float) -> None:
        counts["scans"] += 1
        cache = None if registrations is None else registrations.setdefault(t, {})
        n_solutions, hyps = _hypotheses(scans[t], ego, robots, sigma, _beliefs(bank), cache, counts, kw)
        track.updates.append({j: bank.update(j, h) for j, h in hyps.items()})
        _age(stale, track.updates[-1])
        track.times.append(t)
        track.solutions.append(n_solutions)
        if every is None:
            track.estimates.append({j: bank.estimate(j) for j in bank.known()})
        else:
            track.estimates.append(_kept(bank, t, every, fresh, last, stale))

    for e in events:
        while pending and pending[0] < float(e.t):  # binned: a bin's scan once the stream has passed its end
            scan(pending.pop(0))
        if isinstance(e, Odometry) and e.robot in robots:
            mean, cov = odometry_increment(float(e.v), float(e.w), float(e.dt), noise)
            delta = SE2.to_xytheta(mean)
            if e.robot == ego:
                bank.predict_ego(delta, cov + floor)
            else:
                bank.predict_neighbour(e.robot, delta, cov + floor)
        elif bin_width is None and is_anonymous_detection(e) and float(e.t) not in done:
            done.add(float(e.t))
            scan(float(e.t))
    for t in pending:
        scan(t)
    counts.update({f"bank_{k}": v for k, v in bank.counts.items()})
    track.counts = counts
    return track


def _odometry_noise(events: Sequence[Event], robots: Sequence[int], noise: UnicycleNoise, floor: float):
    """Per robot: odometry stamps and the running sum of its increments' covariances (plus ``floor^2 I``), so that
    the motion noise between two instants is a difference of two rows."""
    out = {}
    for r in robots:
        odo = [e for e in events if isinstance(e, Odometry) and e.robot == r]
        covs = [odometry_increment(float(e.v), float(e.w), float(e.dt), noise)[1] + np.eye(3) * floor**2 for e in odo]
        t = np.array([float(e.t) for e in odo])
        out[r] = (t, np.concatenate([np.zeros((1, 3, 3)), np.cumsum(np.array(covs).reshape(-1, 3, 3), 0)]))
    return out


def _between(table: tuple[np.ndarray, np.ndarray], t0: float, t1: float) -> np.ndarray:
    t, cum = table
    return cum[np.searchsorted(t, t1, side="right")] - cum[np.searchsorted(t, t0, side="right")]


def _new_information(cov: np.ndarray, prev: np.ndarray, motion: np.ndarray) -> np.ndarray | None:
    """Covariance of the information ``cov^-1 - (prev + motion)^-1`` gained since the last hand-off (whose bank
    covariance was ``prev``, moved by the motion noise ``motion`` since); None when nothing was gained. Directions
    without gain get a variance 1e6 times the best one's."""
    info = np.linalg.inv(cov) - np.linalg.inv(prev + motion)
    lam, V = np.linalg.eigh(symmetric(info))
    if lam[-1] <= 0:
        return None
    lam = np.maximum(lam, lam[-1] * 1e-6)
    out = (V / lam) @ V.T
    return symmetric(out)


def lone_detections(events: Iterable[Event]) -> list[Detection]:
    """The anonymous detections (:func:`is_anonymous_detection`) of the stamps where one robot alone scanned: PMR
    registers a scan against another robot's scan of the same instant, so these have no mutual counterpart (MRCLAM's
    cameras are stamped per robot: almost every detection)."""
    observers: dict[float, set[int]] = {}
    anon = [e for e in events if is_anonymous_detection(e)]
    for e in anon:
        observers.setdefault(float(e.t), set()).add(e.observer)
    return [e for e in anon if len(observers[float(e.t)]) == 1]


def bank_detections(
    events: Sequence[Event],
    robots: Sequence[int],
    noise: UnicycleNoise,
    sigma: float,
    *,
    every: float = 1.0,
    inflate: float = 1.0,
    handoff: str = "full",
    lone: bool = False,
    **kw: Any,
) -> tuple[list[Event], dict[int, dict[str, int]]]:
    """The ``anonymous`` association policy as an input to any estimator: every robot runs :func:`track_anonymous`
    on the team's anonymous range-bearing detections and odometry, and its bank's **unambiguous** estimate of each
    met robot ``j`` becomes a tagged relative-pose :class:`~swarmloc.events.Detection` (``kind="pose"``, target
    ``j``: the identity is the one communication gives, the robot whose scan registered), at most one per
    ``(observer, j)`` every ``every`` [s]. The anonymous range-bearing detections are replaced by these; everything
    else passes unchanged.

    The bank's estimates are correlated in time (each is the filter of all scans so far), and a filter fusing them
    as independent measurements counts the same scans again at every hand-off. ``handoff="new"`` hands
    the bank's mean with the covariance of only the information gained since the last hand-off of the pair,
    ``(P_t^-1 - (P_prev + Q)^-1)^-1`` (``P``: the bank's covariances then and now, ``Q``: the odometry noise of
    both robots in between, ego's carried to ``j``'s frame), and skips the hand-off when nothing was gained;
    ``handoff="full"`` (default): the bank's covariance ``P_t`` as is. Measured (docs/association.md), "new" did not
    make the team filter consistent: most of its excess NEES comes from wrong hand-offs (a filter locked on a wrong PMR
    solution), not from the correlation. Either is multiplied by ``inflate``. ``lone``: the anonymous detections
    without a mutual counterpart (:func:`lone_detections`) stay in the events, anonymous, for the nodes to register
    against the team's beliefs (a gated assignment, :mod:`swarmloc.node.associate`); False: every anonymous
    detection is replaced.
    Returns ``(events, counts per robot)`` (the tracker's counters plus ``emitted``, ``no_gain`` and ``lone``, the
    detections passed on); ``kw`` goes to :func:`track_anonymous`."""
    if not every >= 0 or not inflate >= 1.0:
        raise ValueError(f"bank_detections: need every >= 0 s and inflate >= 1, got {every!r}, {inflate!r}")
    if handoff not in ("new", "full"):
        raise ValueError(f"bank_detections: handoff must be 'new' or 'full', got {handoff!r}")
    out = [e for e in events if not is_anonymous_detection(e)]
    passed = lone_detections(events) if lone else []
    counts: dict[int, dict[str, int]] = {}
    new: list[Detection] = []
    shared: dict[float, dict] = {}  # the team's binary registrations per scan, computed once
    motion = _odometry_noise(events, robots, noise, float(kw.get("motion_floor", 1e-3)))
    for ego in robots:
        tr = track_anonymous(events, ego, robots, noise, sigma, every=every, registrations=shared, **kw)
        last: dict[int, tuple[float, np.ndarray]] = {}
        emitted = no_gain = 0
        for t, est in zip(tr.times, tr.estimates, strict=True):
            for j, b in est.items():
                if b.ambiguous or j == ego or t - last.get(j, (-np.inf,))[0] < every:
                    continue
                P = np.asarray(b.gaussian.cov, dtype=float)
                z = SE2.to_xytheta(b.gaussian.mean).astype(float)
                cov: np.ndarray | None = P
                if handoff == "new" and j in last:
                    t0, prev = last[j]
                    A = SE2.Ad(SE2.inverse(b.gaussian.mean))  # ego's noise (left) as a right perturbation of q_j
                    Q = _between(motion[j], t0, t) + A @ _between(motion[ego], t0, t) @ A.T
                    cov = _new_information(P, prev, Q)
                if cov is None:
                    no_gain += 1
                    continue
                cov = cov * inflate
                cov = symmetric(cov)
                if not np.all(np.linalg.eigvalsh(cov) > 1e-12):
                    continue
                new.append(Detection(ego, t, Kind.POSE, readonly(z), readonly(cov), target=int(j)))
                last[j] = (t, P)
                emitted += 1
        n_lone = sum(1 for e in passed if e.observer == ego)
        counts[ego] = {**tr.counts, "emitted": emitted, "no_gain": no_gain, "lone": n_lone}
    out += new + passed
    out.sort(key=sim_order)
    return out, counts
