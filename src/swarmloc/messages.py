"""Messages between nodes: the neighbour exchange as declared types (what the network runtime serializes).

Every exchange belongs to one detection instant of one observer, its **key**: the detection's stamp ``t``, the
observer's robot id and a sub-key ``sub`` (``()`` for a whole detection group; the detection's canonical key
when each detection has its own exchange, as in recursive decentralized fusion). A node answers a query with
its state *before* that key: built from all of its inputs ordered before ``(t, observer, sub)`` and predicted
to ``t`` with the command in force then (:class:`swarmloc.node.base.Node`). The answer is therefore the
same whenever it is asked; when a late input changes it, the node sends it again with a higher revision ``seq``
and the asker re-fuses from ``t``. An answer or update with a ``seq`` lower than one already received is stale
and dropped (and counted).

Types:

* :class:`BeliefQuery` / :class:`BeliefAnswer`: "your belief at my detection ``t``" (thesis estimator,
  distributed EKF, covariance intersection; the thesis' localizer asks a detected neighbour for its belief);
* :class:`ClusterPiece`: ``diekf``'s clusters re-formed, a piece of an old cluster's replica for a new mate;
* :class:`RdlStateQuery` / :class:`RdlState` / :class:`RdlUpdate`: recursive decentralized fusion's pairwise
  exchange (Luft et al. 2018): the observer asks for the target's Cartesian state, covariance and
  cross-covariance factor, computes the joint update, and sends the target its part, naming the revision of
  the state it was computed from (``based_on``), so that an update computed from an outdated state can never
  overwrite a newer one.

Numbers travel as flat tuples (row-major matrices) so that any msgspec encoder (MessagePack, JSON) carries them
without hooks. Conventions: SE(2) means as 3x3 homogeneous matrices, covariances of exponential coordinates
(right perturbation); Cartesian states ``(x, y, theta)`` in metres and radians.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
import numpy as np

from swarmloc.gaussian import GroupGaussian, positive_definite

MAX_FLOATS = 36
"""The most numbers one field of a message carries (a ``6 x 6`` covariance); checked on decoding, before the
tuple is built, so that no field of a received message costs more than that."""
MAX_TEXT = 512
"""The most characters of a message's text (a reason, a group's name), checked on decoding likewise."""
Floats = Annotated[tuple[float, ...], msgspec.Meta(max_length=MAX_FLOATS)]
Text = Annotated[str, msgspec.Meta(max_length=MAX_TEXT)]

SCHEMA_VERSION = 2
"""Version of these messages' wire format (kept equal to :data:`swarmloc.net.schema.SCHEMA_VERSION`). 2: SE(3)
states in :class:`RdlState`, the error dimension ``n`` of :class:`TeamUpdate`, the group of a published belief."""


def flat(a: np.ndarray) -> Floats:
    """A numpy array as a flat tuple of Python floats (row-major)."""
    return tuple(np.asarray(a, dtype=float).ravel().tolist())


class Message(msgspec.Struct, frozen=True, kw_only=True, tag_field="type", tag=True):
    """Common fields: the sending and receiving robot ids, the key's stamp [s] and sub-key."""

    sender: int
    receiver: int
    stamp: float
    sub: Floats = ()

    @property
    def observer(self) -> int:
        """The robot whose detection this exchange belongs to (part of the key)."""
        return self.sender


class BeliefQuery(Message, frozen=True, kw_only=True, tag="belief_query"):
    """Asks ``receiver`` for its belief at ``stamp``, before the sender's detection key."""


class _AnswerFields(Message, frozen=True, kw_only=True):
    """What every answer carries besides its numbers: ``receiver``'s query answered by ``sender`` (so the key's
    observer is the receiver), the answer's revision ``seq``, and ``found=False`` with a ``reason`` when there is
    none."""

    seq: int = 0
    found: bool = True
    reason: Text = ""

    @property
    def observer(self) -> int:
        return self.receiver


class BeliefAnswer(_AnswerFields, frozen=True, kw_only=True, tag="belief_answer"):
    """``receiver``'s query answered by ``sender``: its belief at ``stamp`` (``found=False``: none, see ``reason``)."""

    group: Text = "SE2"
    mean: Floats = ()
    cov: Floats = ()

    def belief(self) -> GroupGaussian:
        """The answered belief as an SE(2) or SE(3) :class:`GroupGaussian` (not validated)."""
        return GroupGaussian(self.group, *self.belief_arrays(), validate=False)

    def belief_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The answered mean ``(3, 3)`` and covariance ``(3, 3)`` as arrays (SE(3): ``(4, 4)`` and ``(6, 6)``)."""
        if self.group == "SE3":
            return np.reshape(np.array(self.mean), (4, 4)), np.reshape(np.array(self.cov), (6, 6))
        return np.reshape(np.array(self.mean), (3, 3)), np.reshape(np.array(self.cov), (3, 3))


class RdlStateQuery(Message, frozen=True, kw_only=True, tag="rdl_state_query"):
    """Asks ``receiver`` (the detected robot ``j``) for ``(x_j, P_jj, sigma_ji)`` before the sender's key."""


class RdlState(_AnswerFields, frozen=True, kw_only=True, tag="rdl_state"):
    """``j``'s Cartesian state ``x`` (3), covariance ``P`` (9) and factor ``sigma`` (9) for the asker ``i``, so that
    ``Sigma_ij = sigma_ij sigma_ji^T``; ``seq`` is the revision of this answer. An SE(3) state (``diekf`` on a 3-D
    team) has ``x`` the pose (16, row-major ``4 x 4``), ``P`` (36) and ``sigma`` (36)."""

    x: Floats = ()
    P: Floats = ()
    sigma: Floats = ()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if len(self.x) == 16:  # an SE(3) state
            return np.reshape(self.x, (4, 4)), np.reshape(self.P, (6, 6)), np.reshape(self.sigma, (6, 6))
        return np.array(self.x), np.reshape(self.P, (3, 3)), np.reshape(self.sigma, (3, 3))


class RdlUpdate(Message, frozen=True, kw_only=True, tag="rdl_update"):
    """The observer's joint update sends the target its new state ``x`` and covariance ``P``, computed from the
    target's answer of revision ``based_on``. Empty ``x`` and ``P``: no update follows that answer (the detection
    was gated or rejected), or an update sent earlier is retracted; either way the target knows the exchange is
    settled."""

    based_on: int = 0
    x: Floats = ()
    P: Floats = ()

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.x), np.reshape(self.P, (3, 3))

    @property
    def empty(self) -> bool:
        """True for "no update follows" or a retraction."""
        return not self.x

    def retraction(self) -> RdlUpdate:
        """This update, emptied: it takes back the update sent under the same key."""
        return msgspec.structs.replace(self, x=(), P=())


class TeamUpdate(Message, frozen=True, kw_only=True, tag="team_update"):
    """One joint update of the exact distributed invariant EKF (:mod:`swarmloc.estimators.diekf`), broadcast by
    the observer (``sender``) to every teammate: the detected robot ``target``, the measurement's world-frame
    Jacobians ``Hi``, ``Hj`` (``m x n`` each), ``Sinv`` (``m x m``, the inverse innovation covariance), ``nu =
    S^-1 r`` (``m``) and the pair's covariances before the update ``Pii``, ``Pjj`` (``n x n`` each); ``n`` the
    dimension of a robot's error (3: SE(2), 6: SE(3)). ``scale``: 1 for an exact update; ``w`` in (0, 1) for a
    clustered team's covariance-intersection update of a robot outside the cluster (every receiver divides its
    covariances by ``w`` first). Empty ``Hi``: the update sent earlier under this key is retracted."""

    target: int = -1
    m: int = 0
    n: int = 3
    Hi: Floats = ()
    Hj: Floats = ()
    Sinv: Floats = ()
    nu: Floats = ()
    Pii: Floats = ()
    Pjj: Floats = ()
    scale: float = 1.0

    @property
    def empty(self) -> bool:
        """True for "the exchange is settled without an update" or a retraction."""
        return not self.Hi

    def retraction(self) -> TeamUpdate:
        """This update, emptied: it takes back the update sent under the same key."""
        return TeamUpdate(sender=self.sender, receiver=self.receiver, stamp=self.stamp, sub=self.sub)


MAX_PIECE = 64
"""The most robots one :class:`ClusterPiece` names (its ``sigma`` carries ``n x n`` numbers for each)."""


class ClusterPiece(Message, frozen=True, kw_only=True, tag="cluster_piece"):
    """At a re-forming of ``diekf``'s clusters (the boundary ``stamp``; :mod:`swarmloc.estimators.cluster_reform`),
    the sender's share of its piece (its old cluster's robots in its new cluster) for a new cluster mate outside the
    piece: the old replica's cross-covariances ``Sigma_sb`` of the sender with each robot ``b`` of ``robots`` (the
    piece's robots after the sender in id order), ``n x n`` each (3: SE(2)), row-major, in that order. The receiver
    builds its new replica from the pieces (:func:`~swarmloc.estimators.cluster_reform.stacked_bound`)."""

    robots: Annotated[tuple[int, ...], msgspec.Meta(max_length=MAX_PIECE)] = ()
    n: int = 3
    sigma: Annotated[tuple[float, ...], msgspec.Meta(max_length=MAX_PIECE * 9)] = ()

    def blocks(self) -> dict[int, np.ndarray]:
        """``b -> Sigma_sb (n, n)`` for each robot of :attr:`robots`."""
        S = np.reshape(np.array(self.sigma, dtype=float), (len(self.robots), self.n, self.n))
        return {int(b): S[k] for k, b in enumerate(self.robots)}


def _finite(xs: tuple, n: int) -> bool:
    if len(xs) != n:
        return False
    if set(map(type, xs)) <= _PLAIN:  # the common case, checked without a Python-level loop
        return all(map(math.isfinite, xs))
    return all(isinstance(x, float | int) and math.isfinite(x) for x in xs)


_PLAIN = {float, int}


def _spd3(c: tuple) -> bool:
    """A row-major 3x3 matrix is symmetric (to 1e-9 relative) and positive definite: the pivots of its Cholesky
    (LDL^T) factorization are > 0, as ``numpy.linalg.cholesky`` decides. (The leading minors, with the determinant
    expanded along a row, refused SPD matrices that Cholesky accepts: the expansion cancels for a badly conditioned
    world-frame covariance, 3.2% of the random ones in ``tests/test_messages.py``.)"""
    scale = max(1.0, max(map(abs, c)))
    if abs(c[1] - c[3]) > 1e-9 * scale or abs(c[2] - c[6]) > 1e-9 * scale or abs(c[5] - c[7]) > 1e-9 * scale:
        return False
    d1 = c[0]
    if not d1 > 0:
        return False
    l10, l20 = c[3] / d1, c[6] / d1
    d2 = c[4] - l10 * c[3]
    if not d2 > 0:
        return False
    l21 = (c[7] - l20 * c[3]) / d2
    return c[8] - l20 * c[6] - l21 * l21 * d2 > 0


def _se2(m: tuple) -> bool:
    """A row-major 3x3 matrix is in SE(2): bottom row (0, 0, 1), rotation block [[c, -s], [s, c]], c^2 + s^2 = 1."""
    c, s = m[0], m[3]
    return (
        m[6] == 0.0 and m[7] == 0.0 and m[8] == 1.0
        and abs(m[4] - c) <= 1e-9 and abs(m[1] + s) <= 1e-9 and abs(c * c + s * s - 1.0) <= 1e-6
    )  # fmt: skip


def _se3_belief_problem(name: str, mean: tuple, cov: tuple) -> str | None:
    """Why an SE(3) belief (16 row-major numbers of a ``4 x 4`` pose, 36 of a ``6 x 6`` covariance) is unusable."""
    if not (_finite(mean, 16) and _finite(cov, 36)):
        return f"{name}: an SE3 mean and cov must be 16 and 36 finite numbers"
    g = np.reshape(np.array(mean, dtype=float), (4, 4))
    R = g[:3, :3]
    if not (np.array_equal(g[3], [0.0, 0.0, 0.0, 1.0]) and np.abs(R.T @ R - np.eye(3)).max() <= 1e-6
            and np.linalg.det(R) > 0):  # fmt: skip
        return f"{name}: mean is not in SE(3)"
    return None if _spd(cov) else f"{name}: cov is not symmetric positive definite"


def _spd(c: tuple) -> bool:
    """A row-major square matrix of finite numbers is symmetric (to 1e-9 relative) and positive definite."""
    k = math.isqrt(len(c))
    C = np.reshape(np.array(c, dtype=float), (k, k))
    return bool(np.abs(C - C.T).max() <= 1e-9 * max(1.0, float(np.abs(C).max()))) and positive_definite(C)


def _se3_state_problem(name: str, x: tuple, P: tuple, sigma: tuple) -> str | None:
    """Why an SE(3) :class:`RdlState` (pose 16, covariance 36, factor 36 numbers) is unusable."""
    if not (_finite(x, 16) and _finite(P, 36) and _finite(sigma, 36)):
        return f"{name}: an SE(3) state's x, P, sigma must be 16, 36 and 36 finite numbers"
    why = _se3_belief_problem(name, x, P)
    return None if why is None else why.replace("cov is", "P is")


def message_problem(m: Message) -> str | None:
    """Why a received message cannot be used, or None: ids not integers, a non-finite stamp or sub-key, and for
    answers and updates the shape, finiteness, SE(2) membership and positive definiteness of their numbers."""
    name = type(m).__name__
    for f in ("sender", "receiver"):
        v = getattr(m, f)
        if not isinstance(v, int) or isinstance(v, bool):
            return f"{name}: {f} must be an integer robot id, got {v!r}"
    if not (isinstance(m.stamp, float | int) and math.isfinite(m.stamp)):
        return f"{name}: stamp must be a finite number of seconds, got {m.stamp!r}"
    if not all(isinstance(x, float | int) and math.isfinite(x) for x in m.sub):
        return f"{name}: sub-key must hold finite numbers"
    if isinstance(m, _AnswerFields) and not m.found:
        return None
    if isinstance(m, BeliefAnswer):
        if m.group == "SE3":
            return _se3_belief_problem(name, m.mean, m.cov)
        if m.group != "SE2":
            return f"{name}: group {m.group!r} is not supported (SE2, SE3)"
        if not (_finite(m.mean, 9) and _finite(m.cov, 9)):
            return f"{name}: mean and cov must be 9 finite numbers each"
        if not _se2(m.mean):
            return f"{name}: mean is not in SE(2)"
        if not _spd3(m.cov):
            return f"{name}: cov is not symmetric positive definite"
    elif isinstance(m, RdlState):
        if len(m.x) == 16:
            return _se3_state_problem(name, m.x, m.P, m.sigma)
        if not (_finite(m.x, 3) and _finite(m.P, 9) and _finite(m.sigma, 9)):
            return f"{name}: x, P, sigma must be 3, 9 and 9 finite numbers"
        if not _spd3(m.P):
            return f"{name}: P is not symmetric positive definite"
    elif isinstance(m, RdlUpdate):
        if not m.x and not m.P:
            return None  # a retraction
        if not (_finite(m.x, 3) and _finite(m.P, 9)):
            return f"{name}: x and P must be 3 and 9 finite numbers"
        if not _spd3(m.P):
            return f"{name}: P is not symmetric positive definite"
    elif isinstance(m, TeamUpdate):
        if not m.Hi:
            return None  # a retraction
        k, d = m.m, m.n
        if not (isinstance(d, int) and d in (3, 6)):
            return f"{name}: n must be 3 (SE(2)) or 6 (SE(3)), got {d!r}"
        if not (isinstance(k, int) and 1 <= k <= d):
            return f"{name}: m must be " + ("1, 2 or 3" if d == 3 else "1 .. 6") + f", got {k!r}"
        sizes = (d * k, d * k, k * k, k, d * d, d * d)
        if not all(_finite(v, n) for v, n in zip((m.Hi, m.Hj, m.Sinv, m.nu, m.Pii, m.Pjj), sizes, strict=True)):
            return f"{name}: Hi, Hj, Sinv, nu, Pii, Pjj must be {sizes} finite numbers"
        spd = _spd3 if d == 3 else _spd
        if not (spd(m.Pii) and spd(m.Pjj)):
            return f"{name}: Pii and Pjj must be symmetric positive definite"
        w = m.scale
        if isinstance(w, bool) or not isinstance(w, int | float) or not 0.0 < w <= 1.0:
            return f"{name}: scale must be a number in (0, 1], got {w!r}"
    elif isinstance(m, ClusterPiece):
        if m.n != 3 or not all(isinstance(b, int) and not isinstance(b, bool) for b in m.robots):
            return f"{name}: n must be 3 (clusters are SE(2) only) and robots integer ids"
        if len(set(m.robots)) != len(m.robots) or m.sender in m.robots or not _finite(m.sigma, 9 * len(m.robots)):
            return f"{name}: robots must be distinct teammates and sigma 9 finite numbers for each"
    return None


Answer = BeliefAnswer | RdlState
AnyMessage = BeliefQuery | BeliefAnswer | RdlStateQuery | RdlState | RdlUpdate | TeamUpdate | ClusterPiece
