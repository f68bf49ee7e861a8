"""Batched team engine: all robots' filters as arrays, one batched step per stamp (:mod:`swarmloc.engine.core`).

* :class:`Engine`: the state and :meth:`Engine.step`; :class:`Detections`: one stamp's detections as arrays;
* :func:`run_engine`: a source's events through the engine, a :class:`~swarmloc.runner.RunResult` comparable to
  :func:`swarmloc.runner.run` with the per-robot nodes (equal to 1e-10: tests/test_engine.py);
* :func:`swarm_run`: simulate and estimate a large swarm (neighbours by ``scipy.spatial.cKDTree``);
* :func:`fusion_step`: micro-benchmark of one predict + relative-pose update step, robot-updates per second.
"""

from swarmloc.engine.core import ENGINE_ESTIMATORS, Detections, Engine
from swarmloc.engine.replay import run_engine
from swarmloc.engine.swarm import fusion_step, swarm_run

__all__ = ["ENGINE_ESTIMATORS", "Detections", "Engine", "fusion_step", "run_engine", "swarm_run"]
