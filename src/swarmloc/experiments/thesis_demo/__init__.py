"""Thesis sec. 5.1 ("Matlab simulation"), the demo behind ``swarmloc demo``: one-shot cooperative localization of a
team started at known poses.

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

``run_demo`` reproduces figures 5.2-5.5 and checks the Gaussians against sampling. Tables 5.1/5.2 (the same
set-up with up to six neighbours) are a research study of the repository's ``swarmloc-studies`` package.

Layout: :mod:`~swarmloc.experiments.thesis_demo.spec` holds the set-up and the model,
:mod:`~swarmloc.experiments.thesis_demo.run` the computations, :mod:`~swarmloc.experiments.thesis_demo.report`
the tables, JSON and figures.
"""

from __future__ import annotations

from swarmloc.experiments.thesis_demo import spec
from swarmloc.experiments.thesis_demo.run import run_demo
from swarmloc.experiments.thesis_demo.spec import *  # noqa: F403 - the set-up and the model: spec.__all__

__all__ = [*spec.__all__, "run_demo"]
