"""Thesis sec. 5.1's printed Tables 5.1/5.2 and its deviation (5.10); the set-up and the model are
:mod:`swarmloc.experiments.thesis_demo.spec`."""

from __future__ import annotations

from typing import Any

import numpy as np

from swarmloc.lie import SE2, wrap_angle

__all__ = ["THESIS_TABLES", "deviation_510"]

THESIS_TABLES: dict[str, dict[str, Any]] = {
    "straight": {
        "table": "5.1",
        # the text conversion lost one column of this row: five values under the printed headers "2 3 4 5 6"
        "mean_deviation": [None, 0.2823, 0.2193, 0.1926, 0.1985, 0.1798],
        "frobenius_norm": [0.095, 0.1554, 0.2027, 0.2413, 0.2721, 0.2982],
        "note": "row 'Mean Sampled Deviation' has 5 printed values for 6 columns (one lost in the text conversion; "
        "shown here under the printed headers 2..6, so n = 1 is unknown)",
    },
    "circular": {
        "table": "5.2",
        "mean_deviation": [0.2234, 0.1585, 0.1606, 0.1520, 0.1697, 0.1461],
        "frobenius_norm": [0.2577, 0.4197, 0.5457, 0.6648, 0.7561, 0.8371],
        "note": "",
    },
}


def deviation_510(g_true: np.ndarray, g_est: np.ndarray) -> np.ndarray:
    """Thesis eq. (5.10) with ``x = (x, y, theta)`` in the world frame, heading difference wrapped. Batched."""
    x_t, x_e = SE2.to_xytheta(g_true), SE2.to_xytheta(g_est)
    d = x_t - x_e
    d[..., 2] = wrap_angle(d[..., 2])
    return np.linalg.norm(d, axis=-1) / np.linalg.norm(x_t, axis=-1)
