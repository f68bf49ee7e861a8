"""Thesis sec. 5.1 ("Matlab simulation"), Tables 5.1/5.2 and figures 5.8/5.9: the accuracy of robot ``i``'s fused
posterior against the number of its neighbours' measurements, in the set-up of the demo
(:mod:`swarmloc.experiments.thesis_demo`, whose set-up and model this package re-exports with
:func:`~swarmloc.experiments.thesis_demo.run_demo`).

* Deviation (5.10) ``||x_true - x_est||_2 / ||x_true||_2`` is ambiguous in the thesis; here ``x = (x, y, theta)`` is
  the Cartesian pose in the world frame (heading difference wrapped to (-pi, pi]). With robot ``i`` starting at
  the origin, ``||x_true||`` averages about 0.8 (straight; 0.65 m travelled plus a heading of std 0.6 rad) and
  2.15 (circular), so the numbers depend on that
  choice of world origin; the tables also give the frame-free errors.

``run_tables`` reproduces Tables 5.1/5.2 and figures 5.8/5.9, :mod:`~swarmloc_studies.thesis_static.pooled` pools
them over many seeds. Run ``python -m swarmloc_studies.thesis_static demo|tables OUT_DIR``.

Layout: :mod:`~swarmloc_studies.thesis_static.spec` holds the thesis' printed tables and eq. (5.10),
:mod:`~swarmloc_studies.thesis_static.run` the computations, :mod:`~swarmloc_studies.thesis_static.report`
the tables, JSON and figures.
"""

from __future__ import annotations

from swarmloc.experiments.thesis_demo import run_demo
from swarmloc.experiments.thesis_demo import spec as demo_spec
from swarmloc.experiments.thesis_demo.spec import *  # noqa: F403 - the set-up and the model: spec.__all__
from swarmloc_studies.thesis_static import spec
from swarmloc_studies.thesis_static.run import run_tables
from swarmloc_studies.thesis_static.spec import *  # noqa: F403 - the printed tables and eq. (5.10): spec.__all__

__all__ = [*demo_spec.__all__, *spec.__all__, "run_demo", "run_tables"]
