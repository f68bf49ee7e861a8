"""Thesis sec. 5.2.2 (the ROS/Gazebo two-robot experiment, Figs 5.14-5.23) and Table 6.1, measured.

:func:`run_dynamic` runs, over many seeds,

1. the two-robot experiment (:func:`swarmloc.sim.thesis_two_robot`, 90 s) at relative-pose noise std 0.01, 0.05
   and 0.1 with five estimators: dead reckoning, the distributed EKF, the thesis estimator (:class:`ExpFusion`,
   second order), its first-order ablation and the centralized EKF (the first-order-optimal reference);
2. the ground-truth-neighbour run (:func:`swarmloc.sim.thesis_ground_truth_neighbour`, 500 s, noise 0.05,
   robot 2 receives absolute fixes), Figs 5.22-5.23;
3. an investigation of the over-confidence of the distributed estimators (fewer detections, one-way fusion,
   the correlation the centralized filter keeps, common-mode vs relative error, order 1 vs 2);

and writes ``dynamic.json`` (every number), ``dynamic.md`` (tables and analysis) and PNG figures.

Conventions: initial poses are known (thesis sec. 5.2.2), so every estimator starts at the true pose with
covariance ``INIT_VAR * I`` (exponential coordinates). Errors are recorded at every odometry step (10 Hz) for both
robots; "team" pools both robots' records. RMSE, heading RMSE and ANEES are per run (time-averaged); spreads are
over seeds (``std`` with ``ddof=1``). ANEES is per degree of freedom (:mod:`swarmloc.evaluation.metrics`).
Times per predict / update are measured by the nodes themselves (``Node.measure_time``, ``time.perf_counter``):
every prediction (odometry, a detection's stamp, an answer to a neighbour, a record) counts as a predict; a
detection group's update is booked net of the predictions inside it.

Layout: :mod:`~swarmloc_studies.thesis_dynamic.spec` holds the set-up (noise levels, durations, the estimator
runs :data:`RUNS`, the double-counting conditions), :mod:`~swarmloc_studies.thesis_dynamic.run` the simulations
and statistics, :mod:`~swarmloc_studies.thesis_dynamic.report` the figures and the output files,
:mod:`~swarmloc_studies.thesis_dynamic.markdown` the Markdown text.
"""

from __future__ import annotations

from swarmloc_studies.thesis_dynamic.run import run_dynamic, spread
from swarmloc_studies.thesis_dynamic.spec import ABLATIONS, INIT_VAR, NOISE_LEVELS, RUNS

__all__ = ["ABLATIONS", "INIT_VAR", "NOISE_LEVELS", "RUNS", "run_dynamic", "spread"]
