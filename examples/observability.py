"""Observability of cooperative localization (lecture slide 20; :mod:`swarmloc_studies.observability`,
:func:`swarmloc.evaluation.observability.unobservable_information`).

    python examples/observability.py [FIGURE.png]

With relative measurements only, the robots' poses relative to each other are observable but the team's pose in
the world is not: the absolute error grows like dead reckoning's while the relative error stays bounded. One robot
with absolute fixes bounds everyone's absolute error. Prints both errors at the end of a 300 s run of the
centralized EKF and, given a file name, draws them over time (RMS over 2 seeds, without and with the fixes).

Last, the same question asked of the filters' own linearizations: the information each filter gains along the three
directions that move the whole team rigidly (x, y, rotation), which no relative measurement can inform. The
standard centralized EKF gains some along the rotation; the invariant EKF none (zero to rounding).
"""

import sys

import numpy as np

from swarmloc.evaluation.observability import unobservable_information
from swarmloc.experiments.sources import load_source
from swarmloc_studies.observability import observability_figure, observability_run

for anchored, name in (((), "relative measurements only"), ((0,), "robot 0 has absolute fixes")):
    errors = observability_run(robots=4, duration=300.0, seed=0, anchored=anchored)
    absolute, relative = (float(np.sqrt(np.mean(errors[k][-1] ** 2))) for k in ("absolute", "relative"))
    print(f"{name}: absolute error {absolute:.3f} m, relative error {relative:.3f} m (RMS at 300 s)")
source = load_source("sim:random", robots=3, duration=20.0, seed=1)  # no landmarks, no fixes
gained = {name: unobservable_information(name, source) for name in ("cekf", "iekf")}
for name, info in gained.items():
    x, y, rotation = np.diag(info["information"])
    print(f"{name}: information along the team's x {x:.2g}, y {y:.2g}, rotation {rotation:.2g} [rad^-2]")
if len(sys.argv) > 1:
    print("figure:", observability_figure(sys.argv[1], seeds=2, duration=60.0))
