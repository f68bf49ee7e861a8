"""Observability analysis as code: the information an estimator gains along the team's unobservable directions.

Without absolute information (no landmarks, no fixes) a rigid motion of the whole team changes no relative
measurement: on SE(2) three directions of the joint state are unobservable. In an estimator's own error
coordinates they are spanned, for robot ``r``, by the columns of ``U_r`` (``3 x 3``): the generators of a
global translation and rotation, ``N(x_r) = [[1, 0, -y_r], [0, 1, x_r], [0, 0, 1]]`` for Cartesian errors at
the initial estimate, the identity for world-frame errors (:mod:`swarmloc.kernels.invariant`).

A linearized filter carries that subspace along with its own transition matrices, ``U_r <- Phi_r U_r`` at every
prediction; an update with Jacobian blocks ``H_b`` (the robots it involves) and noise ``R`` adds the information

    J = M^T R^-1 M,   M = sum_b H_b U_b

along those directions. For the linear system that the filter believes it runs, ``J`` is what the measurement
tells about the team's global pose: zero for every relative measurement of a correct estimator (its Jacobians
annihilate the subspace it propagates: ``H U = 0``), positive for a landmark or an absolute fix. A standard EKF
evaluates its measurement Jacobians at estimates that updates have moved while its ``U`` followed the transition
matrices evaluated elsewhere, so ``H U != 0`` and it gains spurious information about the global rotation
(Huang, Mourikis & Roumeliotis 2011): the cause of its over-confidence without landmarks.

:func:`unobservable_information` runs an estimator over an event stream with its linearization log switched on
(``lin_log``: the estimators that record one are ``cekf``, ``iekf``, ``fej``, ``irdl`` and ``diekf``) and returns
the accumulated ``J``, its trace per update, and the total measurement information for scale. The log holds the
linearizations *as applied*, in the order the filter applied them; run it on an in-order stream without
recording beliefs in between and with lazy odometry runs off (as this function does), so that each prediction of
the filter's own history is logged once and no prediction of a copy is.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from swarmloc.kernels import cartesian as C
from swarmloc.kernels import invariant as I

__all__ = ["SUPPORTED", "information_along", "unobservable_information"]

SUPPORTED = ("cekf", "iekf", "fej", "irdl", "diekf")
"""Estimators that record their linearizations (``lin_log``)."""


@runtime_checkable
class Linearizing(Protocol):
    """A node of the :data:`SUPPORTED` estimators: it appends its linearizations, as applied, to ``lin_log`` (when
    set), with its error coordinates in ``error_frame`` (``"world"`` or ``"cartesian"``)."""

    lin_log: list[tuple[Any, ...]] | None
    error_frame: ClassVar[str]


def information_along(log: list[tuple], bases: Mapping[int, np.ndarray]) -> dict[str, Any]:
    """Accumulate the information along the subspaces ``bases`` (robot -> ``U_r``, ``3 x k``) over a linearization
    log of ``("predict", t, robot, Phi)`` and ``("update", t, {robot: H_b}, R)`` entries (module docstring).

    Returns ``information`` (``k x k``, summed ``J``), ``per_update`` (trace of each update's ``J``), ``times``
    (their stamps) and ``measurement_information`` (the summed trace of ``H^T R^-1 H``, for scale)."""
    U = {r: np.array(b, dtype=float) for r, b in bases.items()}
    k = next(iter(U.values())).shape[1]
    total = np.zeros((k, k))
    per, times = [], []
    scale = 0.0
    for entry in log:
        if entry[0] == "predict":
            _, _, r, Phi = entry
            U[r] = Phi @ U[r]
            continue
        _, t, blocks, R = entry
        Rinv = np.linalg.inv(R)
        M = sum(H @ U[r] for r, H in blocks.items())
        J = M.T @ Rinv @ M
        total += J
        per.append(float(np.trace(J)))
        times.append(float(t))
        scale += float(sum(np.trace(H.T @ Rinv @ H) for H in blocks.values()))
    return {
        "information": total,
        "per_update": np.array(per),
        "times": np.array(times),
        "measurement_information": scale,
    }


def unobservable_information(estimator: str, source: Any, **options: Any) -> dict[str, Any]:
    """Run ``estimator`` (a name in :data:`SUPPORTED`) over ``source`` (a :class:`~swarmloc.experiments.sources.
    Source`) with its linearization log on, and measure the information gained along the team's unobservable
    directions (:func:`information_along`). ``options`` override the node options of the source's configuration.
    """
    from swarmloc.estimators import make_team, node_options
    from swarmloc.runner import run

    if estimator not in SUPPORTED:
        raise ValueError(
            f"{estimator!r} does not record its linearizations; the observability analysis supports {list(SUPPORTED)}"
        )
    opts = {**node_options(estimator, source.config, source.landmarks), **options}
    nodes = make_team(estimator, source.initial, **opts)
    logging = [n for n in nodes if isinstance(n, Linearizing)]
    if len(logging) != len(nodes):
        raise TypeError(f"{estimator!r}'s nodes keep no linearization log (lin_log, error_frame)")
    log: list[tuple[Any, ...]] = []
    for n in logging:
        n.lin_log = log
    for node in nodes:
        node.set_lazy_odometry(False)  # every prediction applied once, in order (a lazy run is re-derived when needed)
    run(nodes, source.events, np.zeros(0))
    world = logging[0].error_frame == "world"
    bases = {}
    for r, b in source.initial.items():
        x, _ = C.from_group(b.mean, b.cov)
        bases[r] = np.eye(3) if world else I.world_basis(x)
    out = information_along(log, bases)
    out["estimator"] = estimator
    out["updates"] = int(out["per_update"].size)
    return out
