"""The one Kalman update of the EKF family, with its chi-square gate and the checks of its result.

Every Cartesian / world-frame EKF of swarmloc (``dekf``, ``rdl``, ``irdl``, ``cekf``, ``iekf``, ``fej``) fuses a
linearized detection with :func:`gated_kalman`: the Joseph-form update
(:func:`swarmloc.kernels.cartesian.kalman_update`, or its block form when only a few columns of a joint state are
observed), then the gate on the normalized innovation squared, then the check that the result is finite and
positive definite. The batched engine applies the same :class:`Gate`. The exponential-coordinate estimators gate
their own pseudo-measurements with the same :class:`Gate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarmloc.gaussian import chi2_ppf, positive_definite
from swarmloc.kernels import cartesian as C

__all__ = [
    "FUSED",
    "NUMERICAL",
    "Gate",
    "Outcome",
    "applied",
    "chi2_ppf",
    "gated_kalman",
    "positive_definite",
    "usable_covariance",
]

Outcome = tuple[str, str]
"""``(outcome, reason)``: outcome ``fused``, ``gated``, ``rejected`` or ``unknown``; reason empty for fused."""

FUSED: Outcome = ("fused", "")
NUMERICAL = "the update is not finite or not positive definite"
NONFINITE = "non-finite innovation"


@dataclass(frozen=True, slots=True)
class Gate:
    """Chi-square gate of probability ``p`` in (0, 1) on a normalized innovation squared; ``p=None``: no gate."""

    p: float | None = None

    def __post_init__(self) -> None:
        if self.p is not None and not (isinstance(self.p, int | float) and 0 < self.p < 1):
            raise ValueError(f"'gate' must be a probability in (0, 1) or None, got {self.p!r}")

    def threshold(self, m: int) -> float:
        """The largest NIS of dimension ``m`` that passes (inf without a gate)."""
        return math.inf if self.p is None else chi2_ppf(self.p, m)

    def verdict(self, nis: float, m: int) -> Outcome | None:
        """None when the innovation passes (or there is no gate); ``("gated", "")`` beyond the gate;
        ``("rejected", "non-finite innovation")`` for a NaN or infinite NIS."""
        if self.p is None:
            return None
        if not math.isfinite(nis):
            return ("rejected", NONFINITE)
        return ("gated", "") if nis > chi2_ppf(self.p, m) else None


def usable_covariance(P: np.ndarray) -> bool:
    """Finite and positive definite (a Cholesky factorization exists)."""
    if P.shape == (3, 3):  # leading minors of the lower triangle (what Cholesky reads), with a margin
        p00, p01, p02, p10, p11, p12, p20, p21, p22 = P.ravel().tolist()
        if all(map(math.isfinite, (p00, p01, p02, p10, p11, p12, p20, p21, p22))):
            m2 = p00 * p11 - p10 * p10
            m3 = p00 * (p11 * p22 - p21 * p21) - p10 * (p10 * p22 - p21 * p20) + p20 * (p10 * p21 - p11 * p20)
            tr = p00 + p11 + p22
            if p00 > 0 and m2 > 1e-9 * tr * tr and m3 > 1e-9 * tr * tr * tr:
                return True
    return positive_definite(P)


def gated_kalman(
    x: np.ndarray,
    P: np.ndarray,
    r: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    gate: Gate,
    *,
    cols: np.ndarray | None = None,
    angles: tuple[int, ...] = (2,),
) -> tuple[np.ndarray, np.ndarray] | Outcome:
    """One gated Kalman update (Joseph form) of ``x (n,)``, ``P (n, n)`` by innovation ``r (m,)`` with Jacobian
    ``H`` and noise ``R (m, m)``; returns ``(x+, P+)``, or the outcome that stops it: gated (or a non-finite NIS)
    by ``gate``, or rejected because the result is not finite and positive definite.

    ``cols``: when given, ``H (m, len(cols))`` holds only the columns of ``x`` the measurement depends on (the
    observer's and the target's blocks of a team's joint state), updated in ``O(n^2 m)``
    (:func:`~swarmloc.kernels.cartesian.kalman_update_blocks`). ``angles``: components of ``x`` wrapped to
    (-pi, pi] after the update; pass ``x = 0`` and ``angles=()`` to get the correction ``K r`` itself (the
    world-frame filters apply it on the group).
    """
    if cols is None:
        xn, Pn, nis_k, ok_k = C.kalman_update(x, P, r, H, R, angles=angles)
        nis, ok = float(nis_k), bool(ok_k)
    else:
        xn, Pn, nis, ok = C.kalman_update_blocks(x, P, r, H, cols, R, angles)
    verdict = gate.verdict(nis, len(r))
    if verdict is not None:
        return verdict
    if not (ok and usable_covariance(Pn)):
        return ("rejected", NUMERICAL)
    return xn, Pn


def applied(x: Any, res: Any) -> tuple[Any, Outcome]:
    """``(res, FUSED)`` for an update's result ``res``, ``(x, res)`` when ``res`` is the outcome that stopped it (a
    ``(str, str)`` pair: ``x`` unchanged)."""
    return (x, res) if isinstance(res[0], str) else (res, FUSED)
