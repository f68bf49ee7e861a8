"""3-D teams as sources: the nodes of an SE(3) estimator for a 3-D team's source, its events with the truth instants
merged in, one run, and the recorded tracks as TUM files.

:func:`run_se3` runs one estimator on one :class:`~swarmloc.datasets.source.Source` of a 3-D team (``sim:3d`` /
``sim:3d_rot``; beliefs recorded at the simulator's truth instants, scored by
:func:`swarmloc.evaluation.metrics.evaluate`: 3-D position RMSE, rotation-angle RMSE, ANEES per dof over the 6 dof);
``swarmloc compare`` runs a 3-D source through :func:`se3_team` and :func:`with_truth`. :func:`write_tum_tracks`
writes each robot's estimate and truth as TUM files with full quaternions (``evo_ape tum truth.tum estimate.tum``).
The study over scenarios x estimators x seeds is the repository's ``swarmloc_studies.se3``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from swarmloc.datasets.source import Source
from swarmloc.datasets.tum import write_tum3
from swarmloc.estimators import accepted_options, estimator_class, make_team
from swarmloc.events import Detection, Event, Odometry, Truth
from swarmloc.node import Node
from swarmloc.runner import RunResult, run

__all__ = ["run_se3", "se3_team", "with_truth", "write_tum_tracks"]


def se3_team(source: Source, estimator: str, **options: Any) -> list[Node]:
    """The nodes of ``estimator`` for a 3-D team's source; ``options`` go to the nodes (``noise`` defaults to
    ``source.noise``, ``t0`` to its start, ``landmarks`` to its landmarks where the estimator takes them)."""
    if source.noise is None:
        raise ValueError(f"source {source.spec!r} is not a 3-D team (no twist noise)")
    base: dict[str, Any] = {"noise": source.noise, "t0": source.t_start}
    if source.landmarks and "landmarks" in accepted_options(estimator_class(estimator, source.initial)):
        base["landmarks"] = source.landmarks
    return make_team(estimator, source.initial, **{**base, **options})


def run_se3(source: Source, estimator: str, **options: Any) -> RunResult:
    """One estimator on a 3-D team's source (:func:`se3_team`), recorded at the source's truth instants."""
    return run(se3_team(source, estimator, **options), with_truth(source), name=estimator)


_PRIO = {Odometry: 0, Detection: 1, Truth: 2}


def with_truth(source: Source) -> list[Event]:
    """The source's events with its truth instants merged in stamp order (at one stamp: odometry, detections,
    truth; the other events keep their order). Appended after the other events instead, a truth instant reaches
    the runner when the nodes' history has moved past it and is not recorded (``record_too_old``): a 20-s run
    scored only its last 76 of 164 instants."""
    return sorted([*source.events, *(source.truth_events or [])], key=lambda e: (e.stamp, _PRIO[type(e)]))


def write_tum_tracks(result: RunResult, out: str | Path) -> list[Path]:
    """Each robot's recorded estimate and truth as ``<out>/<estimator>_robot<N>.tum`` and ``truth_robot<N>.tum``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for r, tr in sorted(result.tracks.items()):
        paths.append(write_tum3(out / f"{result.estimator}_robot{r}.tum", tr.times, tr.mean))
        paths.append(write_tum3(out / f"truth_robot{r}.tum", tr.times, tr.truth))
    return paths
