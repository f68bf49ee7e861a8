"""Robot detections without their identities, for ``swarmloc evaluate`` / ``compare --association`` and benchmarks.

:func:`association_events` turns a source's events into what a team with the policy ``[filter] association``
(:class:`~swarmloc.config.FilterConfig`) sees:

* ``tags``: the identities are given (the reference); with ``clutter`` > 0 the false detections carry no tag and
  every node refuses them, with ``p_detect`` < 1 the same detections are missed as for the other policies;
* ``nearest``, ``joint``: robot detections lose their ``target`` (:func:`swarmloc.sim.anonymous.anonymize`, the
  truth kept in ``truth_target`` for scoring only), misses and Poisson clutter per scan added; the nodes choose
  identities (:mod:`swarmloc.node.associate`);
* ``anonymous``: the same anonymous detections (range-bearing only) go through PMR and a particle-filter bank per
  robot (:func:`swarmloc.association.tracker.bank_detections`), whose unambiguous estimates reach the nodes as
  tagged relative poses with their covariance, once a second, from filters PMR confirmed at that scan; a detection
  of a stamp where no other robot scanned (no mutual counterpart) reaches them anonymous, and the nodes register it
  against the team's beliefs (gated joint assignment, ambiguous refused: the slides' belief-gated case).

:func:`association_accuracy` is the share of anonymous detections given their true identity (a false detection
refused as clutter or ambiguous counts as right), from a run's counters; for ``anonymous``, which gives no
detection an identity but hands off relative poses of named robots, :func:`handoff_accuracy` scores the hand-offs
against the truth instead.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any, get_args

import numpy as np

from swarmloc.association.tracker import bank_detections
from swarmloc.config import Association
from swarmloc.datasets.source import Source
from swarmloc.events import Detection, Event, Kind
from swarmloc.motion import UnicycleNoise
from swarmloc.sim.anonymous import anonymize

__all__ = [
    "POLICIES", "association_accuracy", "association_events", "association_policy", "handoff_accuracy",
    "with_association",
]  # fmt: skip

POLICIES: tuple[Association, ...] = get_args(Association)


def association_policy(value: str) -> Association:
    """``value`` as an association policy, or ``ValueError`` naming the ones there are."""
    for policy in POLICIES:
        if value == policy:
            return policy
    raise ValueError(f"association must be one of {POLICIES}, got {value!r}")


BANK_DEFAULTS: dict[str, Any] = {"n_particles": 200, "max_unmatched": 2, "every": 1.0, "fresh": 0, "lone": True}
"""The bank's settings for ``anonymous`` (200 particles per met robot, two unmatched points per registration for
misses and clutter, one relative pose a second per pair, handed off only from a filter PMR confirmed at that scan:
a filter just drawn from PMR's hypotheses or coasting without one was wrong in about 40% of its hand-offs, measured
on 5 seeds of 4 robots; a detection without a mutual counterpart passed on anonymous, for the nodes' gated
assignment against the team's beliefs, :data:`swarmloc.config.NODE_ASSOCIATION`)."""


def association_events(
    events: Sequence[Event],
    policy: str,
    robots: Sequence[int],
    noise: UnicycleNoise,
    *,
    clutter: float = 0.0,
    p_detect: float = 1.0,
    max_range: float = 5.0,
    seed: int = 0,
    bank: Mapping[str, Any] | None = None,
) -> tuple[list[Event], dict[str, Any]]:
    """The events as the team with ``policy`` sees them (module docstring) and notes for the report (the
    tracker's counters for ``anonymous``). ``clutter``: mean false detections per scan; ``p_detect``: detection
    probability; ``max_range`` [m]: the clutter's range; ``seed``: of misses and clutter."""
    association_policy(policy)
    kw: dict[str, Any] = dict(p_detect=p_detect, clutter=clutter, max_range=max_range, seed=seed, team=set(robots))
    if policy == "tags":
        if clutter == 0 and p_detect == 1:
            return list(events), {}
        return anonymize(events, hide_ids=False, **kw), {}
    anon = anonymize(events, **kw)
    if policy != "anonymous":
        return anon, {}
    covs = [e.cov for e in anon if isinstance(e, Detection) and e.kind == Kind.RANGE_BEARING and e.target_is_robot]
    if not covs:
        raise ValueError(
            "association 'anonymous' needs range-bearing robot detections (PMR registers points): use a source "
            "that has them (sim:range_bearing, mrclam:PATH)"
        )
    opts = {**BANK_DEFAULTS, **(bank or {})}
    sigma = opts.pop("sigma", None)
    if sigma is None:  # the point noise PMR is given: max(s_r, range s_b) of the detections (tracker docstring)
        s = np.sqrt(np.median([[c[0][0], c[1][1]] for c in covs], axis=0))
        sigma = float(max(s[0], 2.0 * s[1]))
    out, counts = bank_detections(anon, list(robots), noise, sigma, **opts)
    return out, {"bank": {str(r): c for r, c in counts.items()}, "bank_sigma_m": sigma}


def association_accuracy(stats: Mapping[str, int]) -> float | None:
    """``right / (right + wrong)`` of a run's association counters; None when no detection was scored."""
    right, wrong = int(stats.get("association_right", 0)), int(stats.get("association_wrong", 0))
    return right / (right + wrong) if right + wrong else None


def handoff_accuracy(events: Sequence[Event], truth: Any, gate: float = 0.999) -> tuple[int, int]:
    """``(right, wrong)`` of the ``anonymous`` policy's hand-offs in ``events`` (its tagged ``"pose"`` detections):
    right when the NEES of the true relative pose of the named robot, ``log(z^-1 (x_i^-1 x_j))`` under the hand-off's
    covariance, is inside the ``gate`` chi-square probability (3 dof; 0.999: 16.27), i.e. the bank named the robot
    that is there. ``truth(robot, times)`` gives ``(T, 3)`` true poses ``(x, y, theta)`` (``Source.truth``)."""
    from swarmloc.gaussian import chi2_ppf, mahalanobis2
    from swarmloc.lie import SE2

    poses = [e for e in events if isinstance(e, Detection) and e.kind == Kind.POSE and e.target is not None]
    if not poses:
        return 0, 0
    t = [np.array([e.t]) for e in poses]
    a = np.array([truth(e.observer, ti)[0] for e, ti in zip(poses, t, strict=True)])
    b = np.array([truth(e.target, ti)[0] for e, ti in zip(poses, t, strict=True)])
    z = SE2.from_xytheta(np.array([e.z for e in poses], dtype=float))
    rel = SE2.inverse(SE2.from_xytheta(a), validate=False) @ SE2.from_xytheta(b)
    y = SE2.log(SE2.inverse(z, validate=False) @ rel, validate=False)
    cov = np.array([e.cov for e in poses], dtype=float)
    right = int(np.sum(mahalanobis2(y, cov) <= chi2_ppf(gate, 3)))
    return right, len(poses) - right


def with_association(src: Source, policy: str | None = None) -> Source:
    """``src`` as a team with the association ``policy`` (None: its configuration's ``[filter] association``) sees
    it: for every policy but ``tags`` the robot ids hidden (no clutter, no misses added), the configuration's policy
    set. What ``swarmloc node`` / ``team`` / ``server`` do with ``--association``: every process of a team applies it
    to the same source, so they all see the same events."""
    policy = src.config.filter.association if policy is None else association_policy(policy)
    config = src.config.with_filter(association=policy)
    if policy == "tags":
        return dataclasses.replace(src, config=config)
    events, _ = association_events(src.events, policy, src.robots, config.motion.noise())
    return dataclasses.replace(src, events=events, config=config)
