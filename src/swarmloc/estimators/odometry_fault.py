"""Truth-free detection of one robot's odometry fault from the mutual detections it takes part in, and the covariance
inflation that lets the team correct the robot instead of absorbing its fault (``diekf``'s ``fault`` option,
``[filter] diekf_fault``).

In the world-frame error (:mod:`swarmloc.kernels.invariant`) the odometry's error transition is the identity, so a
fault of a robot's odometry at time ``tau`` leaves a *constant* world-frame error ``f`` on its pose from then on: a
turn it did not make, by ``delta`` while at ``(x, y)``, is ``f = delta (y, -x, 1)``; a slip is a translation. Each
detection the robot takes part in, as observer or as target, with innovation ``r``, its covariance ``S`` and the
robot's Jacobian block ``H``, is ``r = H f + noise`` under that hypothesis. Over the robot's detections in a window
the generalized likelihood ratio test of such a jump (Willsky & Jones, "A generalized likelihood ratio approach to
the detection and estimation of jumps in linear systems", IEEE TAC 1976; Basseville & Nikiforov, "Detection of
abrupt changes", 1993) is (:func:`jump_test`)

    ``f^ = B^+ b``,  ``T = b^T B^+ b``,  ``b = sum_k H_k^T S_k^-1 r_k``,  ``B = sum_k H_k^T S_k^-1 H_k``,

chi-square of ``rank B`` dof without a fault (to first order, the innovations taken independent). When ``T``
exceeds the ``GAMMA`` quantile of the error's dof and the window's detections involve at least ``PARTNERS`` other
robots (a relative detection cannot say which of its two robots is at fault; a robot that disagrees with two that
do not is), the fault is declared and the robot's covariance is inflated by ``f^ f^T`` (fault accommodation: its
odometry is not trusted over the span, and the next detections correct it rather than its teammates). The window
then starts afresh: the evidence before an alarm is spent.

Only the robot itself inflates its covariance: ``diekf``'s robot owns its ``P_ii``, and an inflation is process
noise (no cross-covariance changes, no replica to keep in step). It reads the innovations of its own detections
(before their update, gated ones too) and those of the detections of it that teammates broadcast (fused ones; a
gated detection's broadcast is empty). Landmark detections do not feed it: with landmarks the filter sees a fault
directly.

The log is keyed by the detection's key, a replay rewriting (or dropping) an entry, and a decision at ``t`` reads the
entries stamped before ``t`` only: a replay gives the in-order run's numbers (as :mod:`.adaptive_noise`'s). So
detections stamped alike do not see one another's entries, and each may raise the same alarm: the inflation is then
that many times ``f^ f^T`` (conservative; in simulation 2 to 6 alarms at the stamp that detects a fault)."""

from __future__ import annotations

from bisect import bisect_left
from typing import Any, NamedTuple

import numpy as np

from swarmloc.messages import RdlState, TeamUpdate
from swarmloc.node import chi2_ppf

__all__ = [
    "GAMMA", "PARTNERS", "WINDOW", "Evidence", "FaultMonitor", "broadcast_evidence", "evidence", "jump_test",
    "observer_evidence",
]  # fmt: skip

GAMMA = 0.9999
"""Chi-square probability of the alarm threshold on ``T`` (the tests' fault-free simulated team, seeds 0 to 5: alarms
in 1 run of 6 at 0.9999, in 3 at 0.999, in 2 of seeds 0 to 2 at 0.99; the test is run at every detection)."""
PARTNERS = 2
"""Fewest other robots the window's detections must involve for an alarm."""
WINDOW = 30.0
"""[s] How far back detections count."""


class Evidence(NamedTuple):
    """One detection's terms for the robot's jump test: ``b = H^T S^-1 r``, ``B = H^T S^-1 H`` and the other robot."""

    b: np.ndarray
    B: np.ndarray
    partner: int


def evidence(H: np.ndarray, Sinv: np.ndarray, nu: np.ndarray, partner: int) -> Evidence:
    """The :class:`Evidence` of a detection with the robot's Jacobian block ``H (m, d)``, inverse innovation
    covariance ``Sinv (m, m)`` and ``nu = S^-1 r (m,)``, the other robot ``partner``."""
    return Evidence(H.T @ nu, H.T @ Sinv @ H, int(partner))


def jump_test(b: np.ndarray, B: np.ndarray) -> tuple[float, np.ndarray]:
    """The generalized likelihood ratio ``T = b^T B^+ b`` of a constant error jump and its estimate ``f^ = B^+ b``
    (module docstring)."""
    f = np.linalg.pinv(B, rcond=1e-9, hermitian=True) @ b
    return float(b @ f), f


class FaultMonitor:
    """The odometry-fault test of one robot (module docstring), a part of its node: :meth:`record` files each
    detection's evidence and says by how much to inflate the robot's covariance.

    ``window`` [s]: how far back detections count; ``gamma``: the alarm's chi-square probability; ``partners``: the
    fewest other robots in the window for an alarm."""

    def __init__(self, window: float = WINDOW, gamma: float = GAMMA, partners: int = PARTNERS) -> None:
        self.window = float(window)
        self.gamma = float(gamma)
        self.partners = int(partners)
        self.alarms: set[tuple[float, Any]] = set()
        """The (stamp, key) of every detection that raised an alarm (a replay that no longer does takes it out)."""
        self._log: dict[tuple[float, Any], tuple[Evidence, bool]] = {}
        """(stamp [s], key) -> (evidence, whether it raised an alarm)"""
        self._stamps: list[float] = []
        self._rows: list[tuple[Evidence, bool]] = []
        self._dirty = False

    def record(self, t: float, key: Any, ev: Evidence | None) -> np.ndarray | None:
        """File the evidence ``ev`` of the detection keyed ``key`` stamped ``t`` [s] (None: it has none, a replay
        drops the entry) and return the inflation ``f^ f^T`` of an alarm, or None."""
        k = (float(t), key)
        self.alarms.discard(k)
        if ev is None:
            self._dirty = self._dirty or self._log.pop(k, None) is not None
            return None
        b, B, partners = ev.b.copy(), ev.B.copy(), {ev.partner}
        for old, _ in self._window(t):
            b += old.b
            B += old.B
            partners.add(old.partner)
        T, f = jump_test(b, B)
        alarm = len(partners) >= self.partners and T > chi2_ppf(self.gamma, len(b))
        self._log[k] = (ev, alarm)
        self._dirty = True
        if not alarm:
            return None
        self.alarms.add(k)
        return np.outer(f, f)

    def _window(self, t: float) -> list[tuple[Evidence, bool]]:
        """The entries stamped in ``[t - window, t)`` and after the stamp of the last alarm among them."""
        if self._dirty:
            self._rebuild(t)
        i0, i1 = bisect_left(self._stamps, t - self.window), bisect_left(self._stamps, t)
        alarms = [self._stamps[i] for i in range(i0, i1) if self._rows[i][1]]
        if alarms:
            i0 = bisect_left(self._stamps, np.nextafter(alarms[-1], np.inf))
        return self._rows[i0:i1]

    def _rebuild(self, t: float) -> None:
        """The entries in stamp order, those no decision reads again forgotten (older than two windows before ``t``
        and the newest: a replay goes back the node's horizon, less than a window)."""
        newest = max([t, *(k[0] for k in self._log)])
        for k in [k for k in self._log if k[0] < newest - 2 * self.window]:
            del self._log[k]
        keys = sorted(self._log, key=lambda k: k[0])
        self._stamps = [k[0] for k in keys]
        self._rows = [self._log[k] for k in keys]
        self._dirty = False


def observer_evidence(protocol: Any, s: Any, d: Any, answer: Any) -> Evidence | None:
    """The observer's :class:`Evidence` of its detection ``d`` of a teammate that answered ``answer`` (an
    :class:`~swarmloc.messages.RdlState`), linearized as ``protocol`` (a
    :class:`~swarmloc.estimators.team_protocol.TeamProtocol`) fuses it from state ``s``; None where it fuses none (not
    a teammate of the replica, a degenerate geometry, a singular ``S``)."""
    j = d.target
    if not isinstance(answer, RdlState) or j not in protocol.pos:
        return None
    xj, Pjj, _ = answer.arrays()
    if xj.shape != s.x.shape:
        return None
    lin = protocol.form.robot(d, s, xj, Pjj, s.Sigma[protocol.pos[protocol.robot], protocol.pos[j]])
    if isinstance(lin, str):
        return None
    r, Hi, _, S, _ = lin
    try:
        Sinv = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return None
    return evidence(Hi, Sinv, Sinv @ r, j)


def broadcast_evidence(u: TeamUpdate, robot: int) -> Evidence | None:
    """The detected robot's :class:`Evidence` of a teammate's broadcast ``u`` of its detection of ``robot`` (None: an
    empty one, of another robot, or a cluster's covariance-intersection update)."""
    if u.empty or u.target != robot or u.sender == robot or u.scale != 1.0:
        return None
    m, n = u.m, u.n
    return evidence(np.reshape(u.Hj, (m, n)), np.reshape(u.Sinv, (m, m)), np.array(u.nu), u.sender)
