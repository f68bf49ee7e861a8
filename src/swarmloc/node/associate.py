"""Association of anonymous robot detections in a node: which teammate each detection of a scan saw.

A robot detection with ``target=None`` (:mod:`swarmloc.sim.anonymous`) is given an identity by the node's policy
(:data:`ASSOCIATIONS`) before the filter fuses it, from the beliefs the node has at the scan's stamp:

* **centralized** (``cekf``): the joint state holds every robot (:mod:`swarmloc.estimators.cekf`);
* **distributed** (:class:`~swarmloc.node.robot.RobotNode`): a node holds only its own robot. For a scan with
  anonymous detections it asks **every teammate** for its belief at the scan's stamp with the query protocol the
  tagged detections use (:class:`~swarmloc.messages.BeliefQuery`, answered from the state before the asker's key,
  revised when a late input changes it), so the choice is the one a centralized filter would make from the
  marginals and is replayed like any other answer. Cost: ``n - 1`` queries and ``n - 1`` answers per scan with
  anonymous detections (a tagged scan costs one pair per detected robot). A teammate that does not answer, or
  answers "not found", is no candidate. The last belief each teammate published, predicted, would cost no
  round trip, but its covariance is stale by the prediction's age and a node does not have a teammate's
  command; the exchange keeps the identities exactly those of the tagged run whenever the policy is right
  (tests/test_association_node.py). ``rdl``, ``irdl``, ``diekf`` and ``flsd`` also ask with their own exchange's
  query, one per anonymous detection and teammate (:mod:`swarmloc.estimators.rdl`), whose answer the detection
  given that teammate is fused from; every node reads the candidates from the ``BeliefQuery`` answers, the beliefs
  before the scan (:meth:`~swarmloc.node.robot.RobotNode._candidates`); ``dr`` associates nothing.

Outcomes (:class:`AssociationView`): a detection given an identity is fused by the filter as a tagged one and
its outcome marked ``association right`` / ``association wrong`` where the truth is known; one left without is
``rejected`` with ``association: clutter`` or ``association: ambiguous`` (``(right)`` / ``(wrong)`` appended where
the truth is known). Counters (:data:`ASSOCIATION_KEYS`, taken back and counted again on a replay like the
outcomes): ``association_associated``, ``_clutter``, ``_ambiguous``, ``_missed`` (teammates predicted within
``sensor_range`` of the observer, and within ``sensor_fov`` of its heading when that is set, that no detection was
given to: only for scans with anonymous detections, and only when ``sensor_range`` is set; ``evaluate`` and
``compare`` set both from the source, :attr:`swarmloc.datasets.source.Source.sensor`), ``_gated`` (associated,
then refused by the filter's innovation gate), ``_right`` and ``_wrong`` (the truth ``truth_target`` is read
**only** for these marks, never for a choice; it is never sent: a node reads it from its own detections where
its source has it, a simulation, and else they stay 0).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from swarmloc.association import AMBIGUOUS, CLUTTER, gate_threshold, innovation_terms, joint, nearest
from swarmloc.events import Detection, Kind
from swarmloc.gaussian import GroupGaussian, world_covariance
from swarmloc.lie import wrap_angle
from swarmloc.node.keys import Group, detection_key
from swarmloc.node.update import Outcome
from swarmloc.sensors.models import MODELS

__all__ = [
    "AMBIGUITY",
    "ASSOCIATIONS",
    "ASSOCIATION_KEYS",
    "AssociationView",
    "answered_beliefs",
    "associate",
    "check_association",
    "check_sensor",
    "is_anonymous",
]

ASSOCIATIONS = ("tags", "nearest", "joint")
"""Policies a node runs: ``tags`` refuses anonymous detections (the identity must be given), ``nearest`` (slide 38,
eq. 8, with an ambiguity margin) and ``joint`` (slide 39, eq. 9) give them one (:mod:`swarmloc.association`)."""
AMBIGUITY = 2.0
"""A detection whose second-best robot (``nearest``), or whose best joint assignment without its robot
(``joint``), costs less than this much more (squared Mahalanobis distance), or which another robot, in its gate or
not, explains by the likelihood at least ``exp(-AMBIGUITY / 2)`` (1/e) times as well as the one chosen (the
innovations' spreads counted: :func:`~swarmloc.association.likely_rivals`), is refused as ambiguous."""
ASSOCIATION_KEYS = tuple(
    f"association_{k}" for k in ("associated", "clutter", "ambiguous", "missed", "gated", "right", "wrong")
)
"""Counters of a node's association step (module docstring)."""


def check_association(where: str, association: str, gate: float) -> None:
    """Raise ValueError for an unknown policy or a gate probability outside ``(0, 1)``."""
    if association not in ASSOCIATIONS:
        raise ValueError(f"{where}: association must be one of {ASSOCIATIONS}, got {association!r}")
    try:
        gate_threshold(2, gate)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: association_gate: {exc}") from None


def check_sensor(where: str, sensor_range: float | None, sensor_fov: float | None) -> None:
    """Raise ValueError unless ``sensor_range`` is None or > 0 [m] and ``sensor_fov`` None or in ``(0, 2 pi]``."""
    if sensor_range is not None and not sensor_range > 0:
        raise ValueError(f"{where}: sensor_range must be > 0 m or None, got {sensor_range!r}")
    if sensor_fov is not None and not 0 < sensor_fov <= 2 * np.pi:
        raise ValueError(f"{where}: sensor_fov must be in (0, 2 pi] rad or None, got {sensor_fov!r}")


def is_anonymous(d: Detection) -> bool:
    """A robot detection without an identity (not an absolute fix)."""
    return d.target is None and d.target_is_robot and d.kind != Kind.ABSOLUTE


@dataclass
class AssociationView:
    """One group with identities given: ``group`` (the detections with their targets set, in the canonical order
    of their new keys, as a tagged group would be fused; the original's answers), ``order`` (``group``'s detection
    ``k`` is the original's ``order[k]``), ``detections`` (the identified detections in the original order),
    ``left`` (original index -> outcome of a detection left without an identity), ``given`` (original indices of
    detections given one), ``missed`` (teammates expected and not given a detection)."""

    group: Group
    order: list[int]
    detections: list[Detection]
    left: dict[int, Outcome]
    given: list[int]
    missed: int

    def outcomes(self, fused: Sequence[Outcome]) -> tuple[list[Outcome], Counter[str]]:
        """The filter's outcomes (in ``group``'s order) in the original group's order with the association's
        marks, and the group's association counters."""
        out: list[Outcome] = [("rejected", "")] * len(fused)
        for k, o in enumerate(fused):
            out[self.order[k]] = o
        c: Counter[str] = Counter()
        c["association_missed"] = self.missed
        for i, o in self.left.items():
            out[i] = o
            c["association_ambiguous" if "ambiguous" in o[1] else "association_clutter"] += 1
            if o[1].endswith("(right)"):
                c["association_right"] += 1
            elif o[1].endswith("(wrong)"):
                c["association_wrong"] += 1
        for i in self.given:
            d = self.detections[i]
            c["association_associated"] += 1
            if out[i][0] == "gated":
                c["association_gated"] += 1
            if d.truth_target is not None:
                right = d.truth_target == d.target
                c["association_right" if right else "association_wrong"] += 1
                if out[i][0] in ("fused", "gated"):
                    out[i] = (out[i][0], "association right" if right else "association wrong")
        return out, +c


def associate(
    g: Group,
    policy: str,
    gate_probability: float,
    observer: GroupGaussian,
    candidates: Mapping[int, GroupGaussian],
    sensor_range: float | None = None,
    sensor_fov: float | None = None,
    cross: Mapping[int, np.ndarray] | None = None,
) -> AssociationView | None:
    """Give the anonymous robot detections of ``g`` identities among ``candidates`` (robot id -> belief at ``g.t``)
    seen from ``observer`` (the observer's belief at ``g.t``) with ``policy`` (``nearest`` or ``joint``), per
    measurement kind; None when the group has none. Beliefs are SE(2) Gaussians (right-perturbation exponential
    coordinates), compared in world ``(x, y, theta)`` to first order. ``sensor_range`` [m] and ``sensor_fov`` [rad]
    (total width centred on the observer's heading; None: all round): the detector's reach, for the missed count.
    ``cross``: a joint filter's world-frame covariance ``(3, 3)`` of the observer's and each candidate's pose, by
    candidate id (:func:`~swarmloc.association.innovation_terms`; None: independent, as a distributed node has them)."""
    dets = list(g.detections)
    anon = [i for i, d in enumerate(dets) if is_anonymous(d)]
    if not anon:
        return None
    ids = sorted(candidates)
    xo, Po = world_covariance(observer.mean, observer.cov)
    if ids:
        xt, Pt = world_covariance(
            np.stack([candidates[r].mean for r in ids]), np.stack([candidates[r].cov for r in ids])
        )
    else:
        xt, Pt = np.zeros((0, 3)), np.zeros((0, 3, 3))
    Pc = None if cross is None else np.asarray([cross[r] for r in ids], dtype=float).reshape(-1, 3, 3)
    left: dict[int, Outcome] = {}
    given: list[int] = []
    got: set[int] = set()
    for kind in sorted({dets[i].kind for i in anon}):
        idx = [i for i in anon if dets[i].kind == kind]
        if MODELS[kind].targets == "self":
            for i in idx:
                left[i] = ("rejected", f"association: kind {kind!r} does not observe another robot")
            continue
        z, R = np.stack([dets[i].z for i in idx]), np.stack([dets[i].cov for i in idx])
        costs, logdet = innovation_terms(kind, z, R, xo, Po, xt, Pt, Pc)
        gate = gate_threshold(MODELS[kind].size, gate_probability)
        if policy == "joint":
            a = joint(costs, gate, ambiguity=AMBIGUITY, logdet=logdet)
        else:
            a = nearest(costs, gate, AMBIGUITY, logdet=logdet)
        for i, j in zip(idx, a.identity.tolist(), strict=True):
            truth = dets[i].truth_target
            if j >= 0:
                dets[i] = replace(dets[i], target=ids[j])
                given.append(i)
                got.add(ids[j])
            else:
                what = "clutter" if j == CLUTTER else "ambiguous" if j == AMBIGUOUS else "none"
                verdict = "" if truth is None else (" (right)" if truth == -1 else " (wrong)")
                left[i] = ("rejected", f"association: {what}{verdict}")
    missed = 0
    if sensor_range is not None and ids:
        dx, dy = xt[:, 0] - xo[0], xt[:, 1] - xo[1]
        near = np.hypot(dx, dy) <= sensor_range
        if sensor_fov is not None:
            bearing = wrap_angle(np.arctan2(dy, dx) - xo[2])
            near &= np.abs(bearing) <= sensor_fov / 2
        missed = sum(1 for r, ok in zip(ids, near.tolist(), strict=True) if ok and r not in got)
    keys = [detection_key(d) for d in dets]
    order = sorted(range(len(dets)), key=lambda i: keys[i])
    view = Group(g.observer, g.t)
    view.detections, view.keys, view.answers = [dets[i] for i in order], [keys[i] for i in order], g.answers
    return AssociationView(view, order, dets, left, sorted(given), missed)


def answered_beliefs(g: Group, robots: Sequence[int]) -> dict[int, GroupGaussian]:
    """The beliefs at ``g.t`` of the ``robots`` that answered ``g``'s queries (sub-key ``()``) with one."""
    out = {}
    for r in robots:
        a: Any = g.answers.get((r, ()))
        if a is not None and getattr(a, "found", False) and hasattr(a, "belief"):
            out[r] = a.belief()
    return out
