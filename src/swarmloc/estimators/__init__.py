"""Estimators as nodes (:mod:`swarmloc.node`): one per robot for the distributed ones, one for the team
for the centralized one. :data:`ESTIMATORS` maps command-line names to node classes; :func:`make_team` builds the
nodes of a team from each robot's initial belief.

=============  ================================  =======================================================================
name           class                             kind
=============  ================================  =======================================================================
``dr``         :class:`DeadReckoning`            prediction only
``expfusion``  :class:`ExpFusion`                the thesis estimator (distributed)
``dekf``       :class:`DistributedEKF`           distributed EKF (thesis baseline)
``ci``         :class:`ExpCI`                    covariance intersection in exponential coordinates (distributed,
                                                 consistent)
``rdl``        :class:`RecursiveDecentralized`   recursive decentralized localization (distributed, pairwise)
``irdl``       :class:`InvariantRDL`             ``rdl`` in world-frame errors (pairwise; third parties still
                                                 approximated)
``diekf``      :class:`DistributedInvariantEKF`  ``iekf`` computed by the robots (exact, a broadcast per update)
``cekf``       :class:`CentralizedEKF`           centralized EKF (reference)
``iekf``       :class:`InvariantEKF`             centralized invariant EKF, world-frame errors
                                                 (observability-preserving)
``fej``        :class:`FirstEstimatesEKF`        centralized EKF with first-estimates Jacobians
                                                 (observability-preserving)
``mcl``        :class:`MonteCarloLocalization`   multi-robot Monte Carlo localization (distributed, particles)
``fls``        :class:`FixedLagSmoother`         per-robot fixed-lag smoother (GTSAM), covariance intersection with
                                                 neighbours
``flsd``       :class:`TeamFixedLagSmoother`     fixed-lag smoother of own landmarks (GTSAM) on ``diekf``'s exchange
=============  ================================  =======================================================================
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

from swarmloc.config import NODE_ASSOCIATION
from swarmloc.estimators.cekf import CentralizedEKF
from swarmloc.estimators.ci import ExpCI
from swarmloc.estimators.dekf import DistributedEKF
from swarmloc.estimators.diekf import DistributedInvariantEKF
from swarmloc.estimators.dr import DeadReckoning
from swarmloc.estimators.expfusion import ExpFusion
from swarmloc.estimators.fls import FixedLagSmoother
from swarmloc.estimators.fls_team import TeamFixedLagSmoother
from swarmloc.estimators.iekf import FirstEstimatesEKF, InvariantEKF
from swarmloc.estimators.irdl import InvariantRDL
from swarmloc.estimators.mcl import MonteCarloLocalization
from swarmloc.estimators.rdl import RecursiveDecentralized
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE3
from swarmloc.node import DEFAULT_HORIZON, Node, RobotNode, TeamNode

if TYPE_CHECKING:
    from swarmloc.config import Config

ESTIMATORS: dict[str, type[Node]] = {
    "dr": DeadReckoning,
    "expfusion": ExpFusion,
    "dekf": DistributedEKF,
    "cekf": CentralizedEKF,
    "iekf": InvariantEKF,
    "fej": FirstEstimatesEKF,
    "ci": ExpCI,
    "rdl": RecursiveDecentralized,
    "irdl": InvariantRDL,
    "diekf": DistributedInvariantEKF,
    "mcl": MonteCarloLocalization,
    "fls": FixedLagSmoother,
    "flsd": TeamFixedLagSmoother,
}
"""Node classes by their command-line name."""

ESTIMATORS_SE3: dict[str, type[Node]] = {
    "dr": DeadReckoning,
    "expfusion": ExpFusion,
    "dekf": DistributedEKF,
    "ci": ExpCI,
    "diekf": DistributedInvariantEKF,
    "cekf": CentralizedEKF,
}
"""The estimators with an SE(3) form (3-D teams), by name: :func:`make_team` picks from this table when the initial
beliefs are on SE(3). Each is the planar class, the initial beliefs' group choosing its form once."""


def estimator_class(estimator: str | type[Node], initial: Mapping[int, GroupGaussian] | None = None) -> type[Node]:
    """The node class of ``estimator`` for a team with these initial beliefs (SE(3) beliefs: :data:`ESTIMATORS_SE3`);
    ValueError for an unknown name or one without an SE(3) form."""
    if not isinstance(estimator, str):
        return estimator
    se3 = initial is not None and any(b.group is SE3 for b in initial.values())
    table = ESTIMATORS_SE3 if se3 else ESTIMATORS
    cls = table.get(estimator)
    if cls is None:
        if se3 and estimator in ESTIMATORS:
            raise ValueError(f"estimator {estimator!r} has no SE(3) form; for a 3-D team choose from {sorted(table)}")
        raise ValueError(f"unknown estimator {estimator!r}; choose from {sorted(table)}")
    return cls


def check_known(estimators: Iterable[str]) -> None:
    """ValueError naming the choices when a name in ``estimators`` is not in :data:`ESTIMATORS`."""
    unknown = [e for e in estimators if e not in ESTIMATORS]
    if unknown:
        raise ValueError(f"unknown estimator(s) {unknown}; choose from {sorted(ESTIMATORS)}")


def accepted_options(cls: type[Node]) -> set[str]:
    """Keyword options a node class accepts (its own and, through ``**kw``, its bases')."""
    names: set[str] = set()
    for klass in cls.__mro__:
        init = vars(klass).get("__init__")  # a class's own; one without takes its base's, met further on
        if klass is object or init is None:
            continue
        params = inspect.signature(init).parameters
        names |= {p.name for p in params.values() if p.kind is inspect.Parameter.KEYWORD_ONLY}
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            break
    return names


def make_team(estimator: str | type[Node], initial: Mapping[int, GroupGaussian], **options: Any) -> list[Node]:
    """The nodes of a team: one per robot for a distributed estimator, one for a centralized one.

    ``estimator``: a name in :data:`ESTIMATORS` or a node class; ``initial``: robot id -> initial belief;
    ``options``: keyword arguments of the class (``noise`` is required). An option the class does not take raises
    TypeError naming it (use :func:`options_for` to pick a common configuration's options per class).
    """
    cls = estimator_class(estimator, initial)
    extra = set(options) - accepted_options(cls)
    if extra:
        raise TypeError(
            f"{cls.__name__} does not take option(s) {sorted(extra)}; it takes {sorted(accepted_options(cls))}"
        )
    if "team" in accepted_options(cls) and "team" not in options:
        options = {**options, "team": tuple(sorted(initial))}
    if issubclass(cls, RobotNode):
        return [cls(r, b, **options) for r, b in sorted(initial.items())]
    if issubclass(cls, TeamNode):
        return [cls(initial, **options)]
    raise TypeError(f"{cls.__name__} is neither a RobotNode (one per robot) nor a TeamNode (one for the team)")


def options_for(estimator: str | type[Node], **candidates: Any) -> dict[str, Any]:
    """The subset of ``candidates`` that ``estimator`` takes (e.g. dead reckoning takes no ``gate``)."""
    cls = ESTIMATORS[estimator] if isinstance(estimator, str) else estimator
    ok = accepted_options(cls)
    return {k: v for k, v in candidates.items() if k in ok}


def node_options(
    name: str,
    config: Config,
    landmarks: Mapping[int, Any] | None,
    t0: float | None = None,
    sensor: tuple[float | None, float | None] = (None, None),
) -> dict[str, Any]:
    """The options of estimator ``name`` taken from ``config`` (those the class accepts); ``t0`` [s]: when the
    initial beliefs hold (the source's start), so that no input before it is taken; ``sensor``: the robot
    detector's ``(range [m], field of view [rad])`` (:attr:`swarmloc.datasets.source.Source.sensor`), given to the
    nodes with an association policy ``nearest`` / ``joint`` for their ``association_missed`` count."""
    f = config.filter
    policy = NODE_ASSOCIATION[f.association]
    choose = policy != "tags"
    return options_for(
        name,
        noise=config.motion.noise(),
        landmarks=landmarks,
        gate=f.gate,
        horizon=f.horizon,
        tolerance=min(f.clock_tolerance, f.horizon),  # the node takes no more (swarmloc.node.clock)
        jump_inputs=f.clock_jump_inputs,
        order=f.order,
        iterations=f.iterations,
        point_iterations=f.point_iterations,
        lag=f.smoother_lag,
        delayed=f.delayed_output,
        cluster=f.diekf_cluster,
        adaptive=f.diekf_adaptive,  # always given: False must reach a diekf whose default is "median"
        **({"reform": f.diekf_reform} if f.diekf_reform else {}),  # the engine's diekf takes no such option
        **({"odocal": True} if f.diekf_odocal else {}),  # nor this one
        **({"fault": True} if f.diekf_fault else {}),  # nor this one
        quarantine=f.quarantine,
        # "anonymous" hands the nodes tagged relative poses and PMR's unregistered detections: they run "joint"
        **({"association": policy} if choose else {}),
        association_gate=f.association_gate,
        **({"sensor_range": sensor[0]} if choose and sensor[0] is not None else {}),
        **({"sensor_fov": sensor[1]} if choose and sensor[1] is not None else {}),
        **({} if t0 is None else {"t0": t0}),
    )


__all__ = [
    "DEFAULT_HORIZON",
    "ESTIMATORS",
    "ESTIMATORS_SE3",
    "CentralizedEKF",
    "DeadReckoning",
    "DistributedEKF",
    "DistributedInvariantEKF",
    "ExpCI",
    "ExpFusion",
    "FirstEstimatesEKF",
    "FixedLagSmoother",
    "TeamFixedLagSmoother",
    "InvariantEKF",
    "InvariantRDL",
    "MonteCarloLocalization",
    "Node",
    "RecursiveDecentralized",
    "RobotNode",
    "accepted_options",
    "check_known",
    "estimator_class",
    "make_team",
    "node_options",
    "options_for",
]
