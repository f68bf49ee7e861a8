"""Thesis sec. 5.1 ("Matlab simulation"): one-shot cooperative localization of a team started at known poses.

Set-up (thesis sec. 5.1, with the choices the text leaves open written down here):

* Differential drive ``r = 0.033`` m, ``l = 0.2`` m, wheel-speed diffusion ``D = 5`` (drift of eq. 5.1 with the
  misprint fixed: yaw rate ``r/l (w1 - w2)``).
* Straight line: ``v = 0.5`` m/s, ``w1 = w2 = v/r``, ``T = 1.3`` s. Circular arc: ``w1 = 26.166``, ``w2 = 21.408``
  rad/s (radius 1 m at 45 deg/s) for ``T = 2`` s, i.e. a quarter circle. The text says "for 1 second" but the
  parameter list says ``T = 2``; ``T = 2`` is used.
* Formation (figures 5.6/5.7 are missing from the text; our choice): all robots start side by side, heading along
  the world x axis; robot ``i`` (the one being localized) starts at the origin, its neighbours at lateral offsets
  ``+0.5, -0.5, +1.0, -1.0, +1.5, -1.5`` m (nearest first, alternating sides). The demo uses the first three
  (a team of four), the tables the first ``n``. All robots receive the same wheel command.
* Each robot's belief is its prediction ``a_k mu(T)``, ``Sigma(T)`` (eqs. 5.3-5.8 via :mod:`swarmloc.motion`;
  ``a_k`` is the known start pose; right perturbation, so ``Sigma`` is the same for every robot).
* The truth is one Euler-Maruyama sample (200 steps) of each robot's SDE; the measurement of neighbour ``k`` by
  robot ``i`` is ``m_ik = (g_i^-1 g_k) exp(n)``, ``n ~ N(0, Sigma_m)``.
* ``Sigma_m`` is printed non-symmetric ((3,1) = 0.002 vs (1,3) = 0.001, (3,2) = 0.0025 vs (2,3) = 0.015); we take
  the upper triangle, ``[[0.01, 0.02, 0.001], [0.02, 0.25, 0.015], [0.001, 0.015, 0.15]]``, which is positive
  definite (eigenvalues 0.0083, 0.148, 0.254).
* Robot ``i`` fuses its prior with the measurements of its neighbours by :func:`swarmloc.fuse_relative`
  (second order, default ``iterations=2``), and for comparison with ``order=1``.
* Deviation (5.10) ``||x_true - x_est||_2 / ||x_true||_2`` is ambiguous in the thesis; here ``x = (x, y, theta)`` is
  the Cartesian pose in the world frame (heading difference wrapped to (-pi, pi]). With robot ``i`` starting at
  the origin, ``||x_true||`` averages about 0.8 (straight; 0.65 m travelled plus a heading of std 0.6 rad) and
  2.15 (circular), so the numbers depend on that
  choice of world origin; the tables also give the frame-free errors.

``run_demo`` reproduces figures 5.2-5.5 and checks the Gaussians against sampling; ``run_tables`` reproduces
Tables 5.1/5.2 and figures 5.8/5.9. Run ``python -m swarmloc.studies.thesis_static demo|tables OUT_DIR``.

Layout: :mod:`~swarmloc.studies.thesis_static.spec` holds the set-up and the model,
:mod:`~swarmloc.studies.thesis_static.run` the computations, :mod:`~swarmloc.studies.thesis_static.report`
the tables, JSON and figures.
"""

from __future__ import annotations

from swarmloc.studies.thesis_static import spec
from swarmloc.studies.thesis_static.run import run_demo, run_tables
from swarmloc.studies.thesis_static.spec import *  # noqa: F403 - the set-up and the model: spec.__all__

__all__ = [*spec.__all__, "run_demo", "run_tables"]
