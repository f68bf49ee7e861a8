"""Observability of cooperative localization (lecture slide 20; :mod:`swarmloc_studies.observability`).

    python examples/observability.py [FIGURE.png]

With relative measurements only, the robots' poses relative to each other are observable but the team's pose in
the world is not: the absolute error grows like dead reckoning's while the relative error stays bounded. One robot
with absolute fixes bounds everyone's absolute error. Prints both errors at the end of a 300 s run of the
centralized EKF and, given a file name, draws them over time (RMS over 2 seeds, without and with the fixes).
"""

import sys

import numpy as np

from swarmloc_studies.observability import observability_figure, observability_run

for anchored, name in (((), "relative measurements only"), ((0,), "robot 0 has absolute fixes")):
    errors = observability_run(robots=4, duration=300.0, seed=0, anchored=anchored)
    absolute, relative = (float(np.sqrt(np.mean(errors[k][-1] ** 2))) for k in ("absolute", "relative"))
    print(f"{name}: absolute error {absolute:.3f} m, relative error {relative:.3f} m (RMS at 300 s)")
if len(sys.argv) > 1:
    print("figure:", observability_figure(sys.argv[1], seeds=2, duration=60.0))
