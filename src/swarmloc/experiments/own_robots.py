"""Your own robots: evaluate an event file (``swarmloc evaluate events``) and make one from a simulation
(``swarmloc simulate``), so that the whole path from a CSV to scores and figures can be tried with no data.

The event format is :mod:`swarmloc.datasets.eventfile`; ground truth, optional, is one TUM file per robot
(``truth_robot<N>.tum``, :mod:`swarmloc.datasets.tum`), looked for beside the event file unless a folder is given.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from swarmloc.config import DEFAULTS, Config
from swarmloc.datasets.eventfile import EventFile, EventFileError, load_events, load_truth_dir
from swarmloc.datasets.eventwrite import write_events
from swarmloc.datasets.tum import interpolate, write_tum
from swarmloc.events import Detection, Odometry
from swarmloc.experiments.evaluate import ALL, evaluate_stream, write_report
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.runner import TruthFn
from swarmloc.sim import RelativeSensor, random_team
from swarmloc.sim.source import sim_source

__all__ = ["evaluate_event_file", "load_event_source", "simulate_to_files"]


def _truth_fn(truth: dict[int, tuple[np.ndarray, np.ndarray]]) -> TruthFn:
    def fn(robot: int, times: np.ndarray) -> np.ndarray:
        if robot not in truth:
            raise ValueError(f"no ground truth for robot {robot}")
        return interpolate(*truth[robot], times)

    return fn


def load_event_source(
    path: Path, config: Config = DEFAULTS, truth_dir: str | os.PathLike[str] | None = None, strict: bool = True
) -> tuple[list, dict[int, GroupGaussian], dict | None, float, float, TruthFn | None]:
    """An event file as ``(events, initial, landmarks, t_start, t_end, truth)`` (see :func:`evaluate_event_file`);
    ``truth`` is None unless every estimated robot has ground truth. The file's ``problems`` are dropped here.
    Raises ValueError when the record grid of ``config`` over the file's span is too large or empty."""
    ef, initial, truth, _, t_start, t_end = _read(Path(path), config, truth_dir, strict)
    return list(ef.events), initial, ef.landmarks, t_start, t_end, truth


_TRUTH_FILE = re.compile(r"truth_robot([0-9]+)\.tum")


def _truth(p: Path, truth_dir: str | os.PathLike[str] | None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Every ``truth_robot<N>.tum`` in ``truth_dir`` (default: beside the event file ``p``)."""
    folder = Path(truth_dir) if truth_dir is not None else p.parent
    ids = sorted(int(m.group(1)) for f in folder.glob("truth_robot*.tum") if (m := _TRUTH_FILE.fullmatch(f.name)))
    return load_truth_dir(folder, ids) if truth_dir is not None or ids else {}


def _span_origin(ef: EventFile) -> str:
    """Where the file's span comes from, for messages: `` (events.csv: first stamp line 3, last end line 9)``."""
    if ef.span is None:
        return f" ({ef.path.name})"
    (_, first), (_, last) = ef.span
    return f" ({ef.path.name}: the first stamp on line {first}, the last end on line {last})"


def _read(p: Path, config: Config, truth_dir: str | os.PathLike[str] | None, strict: bool):  # noqa: ANN202
    truth = _truth(p, truth_dir)
    starts = {r: (float(tr[0][0]), f"the start of its ground truth, truth_robot{r}.tum") for r, tr in truth.items()}
    ef = load_events(p, defaults=config.event_defaults(), strict=strict, starts=starts, team="odometry")
    robots = sorted({e.robot for e in ef.events if isinstance(e, Odometry)})
    if not robots or ef.span is None:
        raise EventFileError(f"{p.name}: no odometry records: nothing to estimate")
    truth = {r: truth[r] for r in robots if r in truth}
    (t_start, _), (t_end, _) = ef.span
    initial = {r: b for r, b in ef.initial_beliefs().items() if r in robots}
    missing = [r for r in robots if r not in initial]
    for r in list(missing):
        if r in truth and truth[r][0][0] <= t_start <= truth[r][0][-1]:
            pose = interpolate(*truth[r], t_start)[0]
            initial[r] = GroupGaussian(SE2, SE2.from_xytheta(pose), config.initial.cov())
            missing.remove(r)
    if missing:
        raise EventFileError(
            f"{p.name}: no initial belief for robot(s) {missing}: add an 'initial' record "
            "(type=initial, robot, z = 'x y theta', std) or ground truth covering the first stamp"
        )
    config.record.count(t_start, t_end, len(robots), _span_origin(ef))
    truth_fn = _truth_fn(truth) if truth and all(r in truth for r in robots) else None
    return ef, initial, truth_fn, sorted(truth), t_start, t_end


def evaluate_event_file(
    path: str | os.PathLike[str],
    estimators: Sequence[str] = ALL,
    truth_dir: str | os.PathLike[str] | None = None,
    config: Config = DEFAULTS,
    out_dir: str | os.PathLike[str] | None = None,
    progress: bool = False,
    strict: bool = True,
) -> dict:
    """Run ``estimators`` on the event file at ``path``, score them against ground truth when there is some, and
    return (and with ``out_dir`` write) the same report as ``swarmloc evaluate mrclam``.

    The estimated robots, the team, are those with odometry: a detection by or of another robot is a bad line.
    Each needs an initial belief: an ``initial`` record, or else its
    ground truth at the first stamp with ``config.initial``'s std. Detections without a noise of their own take
    ``config.sensors``' (:meth:`~swarmloc.config.Config.event_defaults`). Ground truth: every
    ``truth_robot<N>.tum`` of ``truth_dir`` (default: beside the file); a robot's odometry may not start before
    its ground truth when its initial belief comes from there. ``strict=False`` skips bad lines (the report's
    ``problems`` lists the first 20, ``n_bad`` counts them) instead of refusing the file.
    """
    p = Path(path)
    ef, initial, truth_fn, truth_robots, t_start, t_end = _read(p, config, truth_dir, strict)
    report, results = evaluate_stream(
        ef.events,
        initial,
        t_start=t_start,
        t_end=t_end,
        truth=truth_fn,
        landmarks=ef.landmarks,
        estimators=estimators,
        config=config,
        progress=progress,
        span_origin=_span_origin(ef),
    )
    report = {"title": p.name, "file": str(p), "problems": ef.problems, "n_bad": ef.n_bad,
              "truth_robots": truth_robots, **report}  # fmt: skip
    if out_dir is not None:
        write_report(out_dir, "events", report, results, t_start)
    return report


def simulate_to_files(
    out_dir: str | os.PathLike[str],
    robots: int = 4,
    duration: float = 60.0,
    seed: int = 0,
    fmt: str = "csv",
) -> dict[str, Path]:
    """Simulate a random team (:func:`swarmloc.sim.random_team`, relative-pose sensor) and write it as your own
    robots' data would be: ``events.csv`` (or ``.jsonl``) with initial beliefs, ``truth_robot<N>.tum`` and a
    ``config.toml`` holding the simulation's process noise. Events, initial beliefs (drawn about the true starts:
    the truth a sample of each prior) and configuration are :func:`~swarmloc.sim.source.sim_source`'s, so the files
    evaluate as ``sim:random`` of the same seed does. Returns the paths written."""
    if fmt not in ("csv", "jsonl"):
        raise ValueError(f"simulate_to_files: fmt must be 'csv' or 'jsonl', got {fmt!r}")
    sim = random_team(robots, duration, seed=seed, area=3.0, sensor=RelativeSensor(rate=5.0))
    src = sim_source(sim, "sim:random")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    events = [e for e in src.events if isinstance(e, Odometry | Detection)]  # a Source may hold Truth too
    config = src.config
    initial = {r: (SE2.to_xytheta(b.mean), b.cov) for r, b in src.initial.items()}
    paths = {"events": write_events(out / f"events.{fmt}", events, initial=initial,
                                    initial_times=dict.fromkeys(sim.initial_poses, 0.0))}  # fmt: skip
    for j, r in enumerate(sim.robot_ids):
        paths[f"truth_robot{r}"] = write_tum(out / f"truth_robot{r}.tum", sim.times, sim.truth[:, j])
    (out / "config.toml").write_text(
        "# process noise of the simulation that wrote events."
        f"{fmt} (swarmloc simulate --robots {robots} --duration {duration:g} --seed {seed})\n" + config.to_toml()
    )
    paths["config"] = out / "config.toml"
    return paths
