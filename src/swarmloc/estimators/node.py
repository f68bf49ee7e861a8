"""A robot's filter as a **node**: it owns its filter state, clock, odometry command and a bounded history.

One node class runs in every driver: the in-process runner (:mod:`swarmloc.runner`), a network process (one
robot per process) and, through the same kernels, a batched engine. A node never calls anybody: it consumes
inputs with :meth:`Node.step` and returns the messages it wants sent (queries, answers, pairwise updates), so
the driver decides how they travel (sans-I/O).

**Inputs and their keys.** Every input is placed in the node's history by a key ``(t, priority, robot, sub)``:

* ``Odometry(robot, t0, t1, v, w)``: the command ``(v, w)`` is in force from ``t0`` on (until the next command;
  a gap is bridged by holding it). Key ``(t0, 2, robot, ())``. ``t1`` only has to be ``>= t0``.
* Detections of one observer at one instant form one group (in canonical order, duplicates rejected), key
  ``(t, 1, observer, ())``. A group that needs neighbours' answers waits until they are in.
* A pairwise update from a neighbour (recursive decentralized fusion) is keyed by the neighbour's detection,
  ``(t, 1, neighbour, sub)``.

**State as a function of the inputs.** The filter state after a history entry is obtained from the state after
the previous entry by predicting every robot the entry involves from its clock to the entry's stamp with the
command in force, then applying the entry. Hence:

* :meth:`Node.belief_at` ``(t)`` is the belief after all entries stamped ``<= t``, predicted to ``t`` with the
  command in force then: exactly the same whenever it is asked;
* a neighbour's query keyed ``q`` is answered with the state after all entries with key ``< q``, predicted to
  ``q``'s stamp (so two robots that detect each other at the same instant get a fixed, acyclic order: the lower
  robot id first);
* an input that arrives after inputs with later keys is inserted at its key and the entries after it are
  re-applied ("replayed"); an input stamped earlier than ``watermark - horizon`` (``watermark``: the latest key
  stamp seen) or before the node's start is rejected and counted. Within the horizon, the final state does not
  depend on the order in which inputs arrive. When a replay changes an answer the node already gave, it sends
  the answer again with a higher revision ``seq`` and the asker replays from that detection
  (:mod:`swarmloc.messages`).

**Accounting.** Every detection ends in exactly one of ``fused``, ``gated`` (innovation beyond the chi-square
gate), ``rejected`` (with a reason: malformed, degenerate, too old, duplicate, not used by this estimator...) or
``unknown`` (target not known or not answering); replays re-count, they never double count. Odometry is
``used`` or ``rejected`` (with a reason). ``replayed`` counts entries re-applied because of late input.

Subclasses implement the filter: :class:`RobotNode` (one robot: distributed estimators) and the centralized
estimators (one node for the whole team) provide ``_initial_state``, ``_advance``, ``_set_command``,
``_fuse_group``, ``_belief`` and, where they answer neighbours, ``_answer``.
"""

from __future__ import annotations

import logging
import math
import time
from bisect import bisect_left, bisect_right
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from functools import cache
from types import MappingProxyType
from typing import Any, ClassVar

import msgspec
import numpy as np

from swarmloc.events import Detection, Odometry
from swarmloc.gaussian import GroupGaussian, check_covariance
from swarmloc.lie import SE2
from swarmloc.messages import (
    BeliefAnswer,
    BeliefQuery,
    Message,
    RdlState,
    RdlStateQuery,
    RdlUpdate,
    flat,
    message_problem,
)
from swarmloc.motion import UnicycleNoise

log = logging.getLogger(__name__)

Key = tuple[float, int, int, tuple]
"""History key ``(stamp [s], priority, robot id, sub-key)``; see the module docstring."""

P_GROUP = 1
P_ODOMETRY = 2
DEFAULT_HORIZON = 5.0
"""Default history horizon [s]: how far back out-of-order input is replayed instead of rejected."""

KIND_ORDER = {"absolute": 0, "pose": 1, "range_bearing": 2, "range": 3, "bearing": 4}
POINT_KINDS = ("range_bearing", "range", "bearing")
OUTCOMES = ("fused", "gated", "rejected", "unknown")

Landmarks = Mapping[int, tuple[float, float, float, float]]
"""Landmark id -> (x, y, std_x, std_y) in metres."""


@cache
def chi2_ppf(p: float, m: int) -> float:
    """Chi-square quantile (cached: gates use a handful of (p, m) pairs)."""
    from scipy.stats import chi2

    return float(chi2.ppf(p, m))


_VALID_COVS: dict[tuple[int, bytes], bool] = {}
"""Detection covariances already found valid, by ``(dimension, bytes)`` (sensors repeat one covariance)."""


def _clearly_valid(cov: np.ndarray) -> bool:
    """True when ``cov`` is ``1 x 1`` or ``2 x 2``, finite, exactly symmetric and positive definite with a margin
    (``det > 1e-9 trace^2``, so eigenvalues well above rounding): :func:`check_covariance` would accept it. False
    means "not sure": the full check decides."""
    if cov.shape == (1, 1):
        a = float(cov[0, 0])
        return math.isfinite(a) and a > 0
    if cov.shape != (2, 2):
        return False
    a, b, c, d = cov.ravel().tolist()
    if not (b == c and math.isfinite(a) and math.isfinite(b) and math.isfinite(d) and a > 0 and d > 0):
        return False
    return a * d - b * b > 1e-9 * (a + d) ** 2


def validate_detection(d: Detection) -> str | None:
    """Why a detection is unusable, or None when its kind, value and covariance are well formed."""
    try:
        z = np.asarray(d.z, dtype=float)
        cov = np.asarray(d.cov, dtype=float)
    except (TypeError, ValueError) as exc:
        return f"z or cov is not numeric: {exc}"
    want = {"pose": 3, "absolute": 3, "range_bearing": 2, "range": 1, "bearing": 1}.get(d.kind)
    if want is None:
        return f"unknown measurement kind {d.kind!r}"
    if z.shape != (want,):
        return f"z has shape {z.shape}, expected ({want},) for kind {d.kind!r}"
    if not np.isfinite(z).all():
        return "z contains NaN or inf"
    if not (isinstance(d.t, int | float | np.floating) and math.isfinite(d.t)):
        return f"time stamp {d.t!r} is not a finite number"
    seen = (want, cov.tobytes()) if cov.shape == (want, want) else None
    if seen is None or not (_clearly_valid(cov) or seen in _VALID_COVS):
        try:
            check_covariance(cov, want, "detection", "cov")
        except ValueError as exc:
            return str(exc)
        if seen is not None:
            if len(_VALID_COVS) >= 4096:
                _VALID_COVS.clear()
            _VALID_COVS[seen] = True
    if d.kind in ("range_bearing", "range") and z[0] <= 0:
        return f"range must be positive, got {z[0]}"
    if d.target is not None and (not isinstance(d.target, int | np.integer) or isinstance(d.target, bool)):
        return f"target id must be an integer, got {d.target!r}"
    return None


def detection_key(d: Detection) -> tuple[float, ...]:
    """Canonical order of the detections in a group (and the sub-key of per-detection exchanges)."""
    target = -1.0 if d.target is None else float(d.target)
    return (float(KIND_ORDER[d.kind]), 0.0 if d.target_is_robot else 1.0, target, *np.asarray(d.z, float).tolist())


def landmark_state(landmarks: Landmarks | None, lid: int | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Position ``(2,)`` and covariance ``(2, 2)`` of a known landmark, or None."""
    if landmarks is None or lid is None or lid not in landmarks:
        return None
    lx, ly, sx, sy = landmarks[lid]
    return np.array([lx, ly], dtype=float), np.diag([sx * sx, sy * sy])


class Group:
    """The detections one observer made at one instant, in canonical order, and the neighbours' answers."""

    __slots__ = ("observer", "t", "detections", "keys", "answers")

    def __init__(self, observer: int, t: float) -> None:
        self.observer = observer
        self.t = t
        self.detections: list[Detection] = []
        self.keys: list[tuple[float, ...]] = []
        self.answers: dict[tuple[int, tuple], Message] = {}

    def add(self, d: Detection) -> bool:
        """Insert ``d`` in canonical order; False when an identical detection is already there."""
        k = detection_key(d)
        i = bisect_left(self.keys, k)
        if i < len(self.keys) and self.keys[i] == k:
            return False
        self.keys.insert(i, k)
        self.detections.insert(i, d)
        return True


_NOTHING_SENT: Mapping = MappingProxyType({})  # only group entries send messages


class Entry:
    """One history entry: its key, what it is, and the filter state after it (None: not computed yet, an odometry
    entry of a node with :attr:`Node.lazy_odometry`; :meth:`Node._state_at` computes it when it is needed)."""

    __slots__ = ("key", "kind", "data", "state", "outcomes", "sent", "marks")

    def __init__(self, key: Key, kind: str, data: Any) -> None:
        self.key = key
        self.kind = kind  # "odometry", "group" or "update"
        self.data = data
        self.state: Any = None
        self.outcomes: list[tuple[str, str]] | tuple = ()  # replaced, never appended to
        self.sent: dict[tuple[int, tuple], Message] = {} if kind == "group" else _NOTHING_SENT
        self.marks: list[tuple] | tuple = ()  # replaced, never appended to


Outcome = tuple[str, str]
"""``(outcome, reason)``: outcome one of :data:`OUTCOMES`, reason empty for fused."""

FUSED: Outcome = ("fused", "")


class Node:
    """Base class: history, replay, horizon, accounting and the neighbour protocol (see the module docstring).

    Parameters common to all nodes
    ------------------------------
    t0: start time [s] of the initial belief; None: set by :meth:`start` or by the first input's stamp.
    horizon: seconds of history kept for out-of-order input and exact past answers (> 0).
    gate: chi-square gate probability in (0, 1) for innovations, or None (no gating).
    landmarks: known landmarks ``id -> (x, y, std_x, std_y)`` [m].
    use_relative, use_landmarks: whether detections of robots / of landmarks are fused (else rejected, counted).
    """

    name: ClassVar[str] = "node"
    distributed: ClassVar[bool] = True
    over_network: ClassVar[bool] = True
    """False for an estimator whose messages the network driver (:mod:`swarmloc.net.process`) cannot carry."""
    measure_time: bool = False
    """Set True (on a node or a class) to accumulate ``timing``: seconds and counts of predictions and of
    detection-group updates (Table 6.1). Off by default: the clock calls cost about 5% of a replay."""
    lazy_odometry: ClassVar[bool] = False
    """True: an odometry entry appended in order keeps no state; the states of a run of such entries are computed
    when one is needed (a detection group, a belief, an answer), by one call of :meth:`_advance_commands` (which a
    filter can implement for a whole run at once, e.g. preintegrating the odometry). The result is the same as
    computing every entry's state at once. A subclass that reads ``_entries[i].state`` directly leaves it False."""

    def __init__(
        self,
        robots: Sequence[int],
        *,
        t0: float | None = None,
        horizon: float = DEFAULT_HORIZON,
        gate: float | None = None,
        landmarks: Landmarks | None = None,
        use_relative: bool = True,
        use_landmarks: bool = True,
    ) -> None:
        cls = type(self).__name__
        if not (isinstance(horizon, int | float) and math.isfinite(horizon) and horizon > 0):
            raise ValueError(f"{cls}: 'horizon' must be a positive number of seconds, got {horizon!r}")
        if gate is not None and not (isinstance(gate, int | float) and 0 < gate < 1):
            raise ValueError(f"{cls}: 'gate' must be a probability in (0, 1) or None, got {gate!r}")
        self.robots: tuple[int, ...] = tuple(robots)
        self.horizon = float(horizon)
        self.gate = gate
        self.landmarks = landmarks
        self.use_relative = use_relative
        self.use_landmarks = use_landmarks
        self.counts: Counter[str] = Counter()
        """Counters (see :meth:`stats`): detections in and their outcome (``fused``, ``gated``, ``rejected``,
        ``unknown``), odometry in and its outcome (``odometry_used``, ``odometry_rejected``), late inputs and the
        entries they made re-apply (``late``, ``replayed``), messages in and rejected, answers and revisions sent."""
        self.reasons: Counter[str] = Counter()
        """Why inputs were rejected or unknown: ``"rejected: <reason>"`` -> count."""
        self.ledger: Counter[tuple] | None = None
        """Set to a Counter to track the outcome of every applied detection by measurement id: ``(observer, t,
        detection key, outcome) -> count`` (replays take the old outcome back). A correct node has, for every
        measurement, exactly one outcome counted once: nothing fused twice."""
        self.timing = {"predict_s": 0.0, "predict_n": 0, "fuse_s": 0.0, "fuse_n": 0}
        """With ``measure_time``: seconds and counts of predictions and of detection-group updates (net of the
        predictions inside them)."""
        self._keys: list[Key] = []
        self._entries: list[Entry] = []
        self._base: Any = None
        self._base_key: Key | None = None
        self._t0: float | None = None
        self._watermark = -math.inf
        self._pending: dict[Key, Group] = {}
        self._served_keys: list[tuple[Key, int, str]] = []
        self._served: dict[tuple[Key, int, str], Message] = {}
        self._since_prune = 0
        self._neighbours: set[int] = set()
        if t0 is not None:
            self.start(t0)

    # ------------------------------------------------------------------------------------------------ public
    @property
    def started(self) -> bool:
        return self._t0 is not None

    @property
    def t0(self) -> float | None:
        """Start time [s] of the initial belief (None until started)."""
        return self._t0

    @property
    def watermark(self) -> float:
        """Latest stamp [s] of any input in the history (``-inf`` before the first)."""
        return self._watermark

    @property
    def clock(self) -> float | None:
        """Stamp [s] of the latest history entry (the node's time), or ``t0``."""
        return self._keys[-1][0] if self._keys else self._t0

    @property
    def history_size(self) -> int:
        """Entries kept in the history (bounded: about the inputs of one horizon, plus at most 64 not yet pruned)."""
        return len(self._entries)

    @property
    def neighbours(self) -> frozenset[int]:
        """Robots this node has heard from (an answer that found a belief, or a pairwise update): it starts with
        none and learns them as they appear."""
        return frozenset(self._neighbours)

    @property
    def pending(self) -> int:
        """Detection groups waiting for neighbours' answers."""
        return len(self._pending)

    @property
    def first_pending(self) -> Key | None:
        """Key of the earliest detection group waiting for answers (None: none waits). A driver that holds a
        neighbour's query keyed after it until it is applied avoids answering twice (answer, then revision)."""
        return min(self._pending) if self._pending else None

    def start(self, t0: float) -> None:
        """Set the time [s] at which the initial belief holds (once)."""
        if not (isinstance(t0, int | float | np.floating) and math.isfinite(t0)):
            raise ValueError(f"{type(self).__name__}.start: t0 must be a finite time in seconds, got {t0!r}")
        if self._t0 is not None:
            if float(t0) != self._t0:
                raise ValueError(f"{type(self).__name__}.start: already started at t0 = {self._t0}, got {t0}")
            return
        self._t0 = float(t0)
        self._base = self._initial_state(self._t0)
        self._base_key = (self._t0, -1, -1, ())
        self._watermark = max(self._watermark, self._t0)

    def step(self, item: Odometry | Detection | Iterable[Detection] | Message) -> list[Message]:
        """Consume one input (odometry, one or several detections, or a message from a neighbour) and return the
        messages to send. Never raises on bad data: it is rejected and counted (``counts``, ``reasons``)."""
        if isinstance(item, Odometry):
            return self._on_odometry(item)
        if isinstance(item, Detection):
            return self._on_detections([item])
        if isinstance(item, Message):
            return self._on_message(item)
        if isinstance(item, Iterable) and not isinstance(item, str | bytes):
            items = list(item)
            if all(isinstance(d, Detection) for d in items):
                return self._on_detections(items)
        self._count_message_rejected(f"unsupported input of type {type(item).__name__}")
        return []

    def belief_at(self, t: float, robot: int | None = None) -> GroupGaussian:
        """Belief of ``robot`` (default: the node's own) at time ``t`` [s]: after every entry stamped ``<= t``,
        predicted to ``t`` with the command in force then. Raises ValueError for ``t`` before the kept history."""
        robot = self._robot_arg(robot)
        if self._t0 is None:
            raise ValueError(f"{type(self).__name__}.belief_at: the node has not started (no input yet, no t0)")
        if not t >= self._base_key[0]:
            raise ValueError(
                f"{type(self).__name__}.belief_at: t = {t} is before the kept history (from {self._base_key[0]}); "
                f"the horizon is {self.horizon} s"
            )
        pos = bisect_right(self._keys, (t, 3))
        return self._belief(self._adv(self._state_at(pos - 1), robot, t), robot)

    def belief(self, robot: int | None = None) -> GroupGaussian:
        """Belief of ``robot`` at the node's clock (its latest entry)."""
        robot = self._robot_arg(robot)
        return self.belief_at(self.clock, robot)

    def stats(self) -> dict[str, int]:
        """A copy of the counters, every key present (zeros included), and ``pending``: detections still waiting
        for an answer. ``detections == fused + gated + rejected + unknown + pending`` at all times."""
        keys = ("detections", *OUTCOMES, "odometry", "odometry_used", "odometry_rejected", "late", "replayed",
                "messages", "messages_rejected", "answers_sent", "revisions_sent")  # fmt: skip
        out = dict.fromkeys(keys, 0)
        out.update(self.counts)
        out["pending"] = sum(len(g.detections) for g in self._pending.values())
        return out

    def expire(self, before: float | None = None) -> list[Message]:
        """Give up waiting for answers to groups stamped before ``before`` (default: all): their detections that
        still miss an answer are counted ``unknown`` ("no answer"). Drivers call it on a timeout or at the end."""
        out: list[Message] = []
        for key in sorted(self._pending):
            if before is None or key[0] < before:
                g = self._pending.pop(key)
                out += self._commit_group(key, g)
        return out

    # ------------------------------------------------------------------------------------------------ hooks
    def _initial_state(self, t0: float) -> Any:
        raise NotImplementedError

    def _advance(self, s: Any, robot: int, t: float) -> Any:
        """State with ``robot`` predicted to ``t`` (unchanged, the same object, when it is already there)."""
        raise NotImplementedError

    def _set_command(self, s: Any, robot: int, v: float, w: float) -> Any:
        raise NotImplementedError

    def _advance_commands(self, s: Any, cmds: Sequence[tuple[float, int, float, float]]) -> Any:
        """State after a run of odometry entries ``cmds = [(t [s], robot, v [m/s], w [rad/s]), ...]`` (in key order):
        each robot predicted to ``t``, then its command set. A filter may override it with a faster equivalent (the
        same result to rounding); the default applies :meth:`_advance` and :meth:`_set_command` one by one."""
        for t, robot, v, w in cmds:
            s = self._set_command(self._adv(s, robot, t), robot, v, w)
        return s

    def _fuse_group(self, s: Any, g: Group) -> tuple[Any, list[Outcome], list[Message]]:
        """Apply a complete detection group to ``s`` (the observer already predicted to ``g.t``)."""
        raise NotImplementedError

    def _belief(self, s: Any, robot: int) -> GroupGaussian:
        raise NotImplementedError

    def _requests(self, g: Group) -> list[Message]:
        """Queries a group needs before it can be applied (default: none)."""
        return []

    def _answer(self, s: Any, q: Message) -> Message | None:
        """Answer a query from state ``s`` (predicted to the query's stamp); None: this node does not answer it."""
        return None

    def _apply_update(self, s: Any, u: RdlUpdate) -> Any:
        raise NotImplementedError

    # ------------------------------------------------------------------------------------------------ targets
    def _needs_answer(self, g: Group, d: Detection) -> bool:
        """True when fusing ``d`` needs the target robot's answer (distributed nodes)."""
        return (
            d.kind != "absolute"
            and d.target_is_robot
            and self.use_relative
            and d.target is not None
            and d.target != g.observer
        )

    def _classify(self, g: Group, d: Detection, sub: tuple = ()) -> tuple[str, Any]:
        """What ``d`` is of: ``("absolute", None)``, ``("robot", answer)``, ``("landmark", (p, C))``, or the outcome
        ``("rejected" | "unknown", reason)`` when it cannot be fused."""
        if d.kind == "absolute":
            return ("absolute", None)
        if d.target_is_robot:
            if not self.use_relative:
                return ("rejected", "relative measurements are switched off")
            if d.target is None:
                return ("rejected", "robot detection without a target id")
            if d.target == g.observer:
                return ("rejected", "the target is the observer itself")
            return self._robot_target(g, d, sub)
        if d.kind == "pose":
            return ("rejected", "a landmark is a point: it has no relative pose")
        if not self.use_landmarks:
            return ("rejected", "landmark measurements are switched off")
        lm = landmark_state(self.landmarks, d.target)
        if lm is None:
            return ("unknown", f"landmark {d.target} is not in the map")
        return ("landmark", lm)

    def _robot_target(self, g: Group, d: Detection, sub: tuple) -> tuple[str, Any]:
        """A distributed node knows a neighbour only from its answer."""
        a = g.answers.get((d.target, sub))
        if a is None:
            return ("unknown", f"no answer from robot {d.target}")
        if not a.found:
            return ("unknown", f"robot {d.target}: {a.reason}")
        return ("robot", a)

    def _gated(self, nis: float, m: int) -> Outcome | None:
        """The outcome of the chi-square gate for a normalized innovation squared ``nis`` of dimension ``m``."""
        if self.gate is None:
            return None
        if not math.isfinite(nis):
            return ("rejected", "non-finite innovation")
        if nis > chi2_ppf(self.gate, m):
            return ("gated", "")
        return None

    # ------------------------------------------------------------------------------------------------ counting
    def _robot_arg(self, robot: int | None) -> int:
        if robot is None:
            if len(self.robots) != 1:
                raise ValueError(f"{type(self).__name__}: say which robot ({list(self.robots)})")
            return self.robots[0]
        if robot not in self.robots:
            raise KeyError(f"{type(self).__name__}: unknown robot id {robot!r} (this node has {list(self.robots)})")
        return robot

    def _outcome(self, outcome: Outcome, sign: int = 1) -> None:
        self.counts[outcome[0]] += sign
        if outcome[1]:
            self.reasons[f"{outcome[0]}: {outcome[1]}"] += sign

    def _reject_detection(self, d: Detection, reason: str) -> None:
        self._outcome(("rejected", reason))
        log.debug("%s: detection by %s at t=%s rejected: %s", self.name, d.observer, d.t, reason)

    def _reject_odometry(self, reason: str) -> None:
        self.counts["odometry_rejected"] += 1
        self.reasons[f"odometry rejected: {reason}"] += 1

    def _count_message_rejected(self, reason: str) -> None:
        self.counts["messages_rejected"] += 1
        self.reasons[f"message rejected: {reason}"] += 1
        log.debug("%s: message rejected: %s", self.name, reason)

    def _too_old(self, t: float) -> str | None:
        if self._t0 is not None and t < self._t0:
            return f"stamp {t} is before the node's start time {self._t0}"
        if t < self._watermark - self.horizon:
            return "older than the history horizon"
        return None

    def _ensure_started(self, t: float) -> None:
        if self._t0 is None:
            self.start(t)

    # ------------------------------------------------------------------------------------------------ timing
    def _adv(self, s: Any, robot: int, t: float) -> Any:
        if not self.measure_time:
            return self._advance(s, robot, t)
        t_start = time.perf_counter()
        s2 = self._advance(s, robot, t)
        if s2 is not s:
            self.timing["predict_s"] += time.perf_counter() - t_start
            self.timing["predict_n"] += 1
        return s2

    # ------------------------------------------------------------------------------------------------ inputs
    def _odometry_fast(self, e: Odometry) -> bool:
        """Consume ``e`` if it takes the common path: valid, in order (after every entry), nothing to revise and no
        pruning due; False (nothing changed) otherwise, for :meth:`step` to handle it. A driver may call it before
        :meth:`step` (same result, less overhead)."""
        t0, t1, v, w = e.t0, e.t1, e.v, e.w
        if not (type(t0) is type(t1) is type(v) is type(w) is float) or self._since_prune >= 63:
            return False
        robot = e.robot
        start = self._t0
        if start is None or robot not in self.robots or not (start <= t0 <= t1) or t0 < self._watermark - self.horizon:
            return False
        if not (math.isfinite(t1) and math.isfinite(v) and math.isfinite(w)):  # t0 is finite: start <= t0 <= t1
            return False
        key: Key = (t0, P_ODOMETRY, robot, ())
        keys = self._keys
        if (keys and not keys[-1] < key) or (self._served_keys and self._served_keys[-1][0] > key):
            return False
        counts = self.counts
        counts["odometry"] += 1
        counts["odometry_used"] += 1
        entry = Entry(key, "odometry", (robot, v, w))
        if not self.lazy_odometry:
            s = self._entries[-1].state if self._entries else self._base
            entry.state = self._set_command(self._adv(s, robot, t0), robot, v, w)
        keys.append(key)
        self._entries.append(entry)
        if t0 > self._watermark:
            self._watermark = t0
        self._since_prune += 1
        return True

    def _on_odometry(self, e: Odometry) -> list[Message]:
        if self._odometry_fast(e):
            return []
        self.counts["odometry"] += 1
        if e.robot not in self.robots:
            self._reject_odometry(f"robot {e.robot!r} is not a robot of this node")
            return []
        try:
            finite = math.isfinite(e.t0) and math.isfinite(e.t1) and math.isfinite(e.v) and math.isfinite(e.w)
        except TypeError:
            finite = False
        if not finite:
            self._reject_odometry("non-finite or non-numeric time or speed")
            return []
        if e.t1 < e.t0:
            self._reject_odometry("t1 before t0")
            return []
        self._ensure_started(e.t0)
        why = self._too_old(e.t0)
        if why:
            self._reject_odometry(why)
            return []
        key: Key = (float(e.t0), P_ODOMETRY, e.robot, ())
        keys = self._keys
        pos = len(keys) if not keys or keys[-1] < key else bisect_left(keys, key)
        if pos < len(keys) and keys[pos] == key:
            _, v, w = self._entries[pos].data
            self._reject_odometry("duplicate" if (v, w) == (e.v, e.w) else "a different command at the same t0")
            return []
        self.counts["odometry_used"] += 1
        v, w = float(e.v), float(e.w)
        entry = Entry(key, "odometry", (e.robot, v, w))
        if pos < len(keys) or self._since_prune >= 63 or (self._served_keys and self._served_keys[-1][0] > key):
            return self._insert(pos, entry)
        # in order, nothing to revise or prune (a start time or a number :meth:`_odometry_fast` did not take)
        keys.append(key)
        if not self.lazy_odometry:
            s = self._entries[-1].state if self._entries else self._base
            entry.state = self._set_command(self._adv(s, e.robot, key[0]), e.robot, v, w)
        self._entries.append(entry)
        if key[0] > self._watermark:
            self._watermark = key[0]
        self._since_prune += 1
        return []

    def _on_detections(self, dets: list[Detection]) -> list[Message]:
        groups: dict[tuple[int, float], list[Detection]] = {}
        for d in dets:
            self.counts["detections"] += 1
            why = validate_detection(d)
            if why is None and d.observer not in self.robots:
                why = f"observer {d.observer!r} is not a robot of this node"
            if why is None:
                self._ensure_started(float(d.t))
                why = self._too_old(float(d.t))
            if why is not None:
                self._reject_detection(d, why)
                continue
            groups.setdefault((d.observer, float(d.t)), []).append(d)
        out: list[Message] = []
        for (obs, t), ds in groups.items():
            out += self._add_detections(obs, t, ds)
        return out

    def _add_detections(self, observer: int, t: float, ds: list[Detection]) -> list[Message]:
        key: Key = (t, P_GROUP, observer, ())
        pending = self._pending.get(key)
        g = pending if pending is not None else Group(observer, t)
        added = []
        pos = bisect_left(self._keys, key)
        applied = self._entries[pos].data if pos < len(self._keys) and self._keys[pos] == key else None
        for d in ds:
            if (applied is not None and detection_key(d) in applied.keys) or not g.add(d):
                self._reject_detection(d, "duplicate detection")
            else:
                added.append(d)
        if not added:
            return []
        if applied is not None:  # the answers already received serve the new detections too
            g.answers = {**applied.answers, **g.answers}
        queries = [q for q in self._requests(g) if (q.receiver, q.sub) not in g.answers]
        for q in queries:
            g.answers[(q.receiver, q.sub)] = None
        waiting = pending is not None and any(v is None for v in g.answers.values())
        if queries or waiting:
            self._pending[key] = g
            return queries
        self._pending.pop(key, None)
        return self._commit_group(key, g)

    def _commit_group(self, key: Key, g: Group) -> list[Message]:
        """Put a group whose answers are all in (or given up) into the history and apply it."""
        pos = bisect_left(self._keys, key)
        if pos < len(self._keys) and self._keys[pos] == key:  # merge into the applied group
            old: Group = self._entries[pos].data
            for d in g.detections:
                old.add(d)
            old.answers.update({k: v for k, v in g.answers.items() if v is not None})
            return self._recompute(pos, late=True)
        if key[0] < self._watermark - self.horizon:  # waited too long: beyond the horizon now
            for d in g.detections:
                self._reject_detection(d, "older than the history horizon")
            return []
        return self._insert(pos, Entry(key, "group", g))

    def _on_message(self, m: Message) -> list[Message]:
        self.counts["messages"] += 1
        if not (isinstance(m.stamp, int | float) and math.isfinite(m.stamp)):
            self._count_message_rejected("non-finite stamp")
            return []
        ids_ok = all(isinstance(x, int) and not isinstance(x, bool) for x in (m.sender, m.receiver))
        if not (ids_ok and isinstance(m.sub, tuple) and all(isinstance(x, int | float) for x in m.sub)):
            self._count_message_rejected("robot ids must be integers and the sub-key a tuple of numbers")
            return []
        if isinstance(m, BeliefQuery | RdlStateQuery):
            return self._on_query(m)
        if isinstance(m, BeliefAnswer | RdlState):
            return self._on_answer(m)
        if isinstance(m, RdlUpdate):
            return self._on_update(m)
        self._count_message_rejected(f"unexpected message type {type(m).__name__}")
        return []

    # ------------------------------------------------------------------------------------------------ history
    def _insert(self, pos: int, entry: Entry) -> list[Message]:
        if entry.key[0] > self._watermark:
            self._watermark = entry.key[0]
        if pos == len(self._keys):  # in order: the common case, one entry applied
            self._keys.append(entry.key)
            self._entries.append(entry)
            if self.lazy_odometry and entry.kind == "odometry":
                out = []
            else:
                entry.state, out, dead = self._apply(self._state_at(pos - 1), entry)
                if dead:
                    del self._keys[pos], self._entries[pos]
            if self._served_keys and self._served_keys[-1][0] > entry.key:
                out += self._revise(entry.key)
        else:
            self._keys.insert(pos, entry.key)
            self._entries.insert(pos, entry)
            out = self._recompute(pos, late=True)
        self._since_prune += 1
        if self._since_prune >= 64:
            self._prune()
        return out

    def _recompute(self, pos: int, late: bool, changed: Key | None = None) -> list[Message]:
        """Re-apply the entries from ``pos`` on, re-count their outcomes, and revise the answers they change
        (those keyed after ``changed``, the first key whose state may differ: default the entry at ``pos``)."""
        entries = self._entries
        if changed is None:
            changed = entries[pos].key
        lazy = self.lazy_odometry
        if lazy:  # the states after pos are recomputed: none of them may serve as the start of a lazy run
            for e in entries[pos:]:
                e.state = None
        s = self._state_at(pos - 1)
        out: list[Message] = []
        dead: list[int] = []
        if late:
            self.counts["late"] += 1
            self.counts["replayed"] += len(entries) - pos - 1
        for i in range(pos, len(entries)):
            e = entries[i]
            if lazy:
                if e.kind == "odometry":
                    continue
                s = self._state_at(i - 1)
            s, msgs, is_dead = self._apply(s, e)
            e.state = s
            out += msgs
            if is_dead:
                dead.append(i)
        for i in reversed(dead):
            del entries[i]
            del self._keys[i]
        out += self._revise(changed)
        return out

    def _apply(self, s: Any, e: Entry) -> tuple[Any, list[Message], bool]:
        """Apply one history entry to the state before it: ``(state after, messages, entry now void)``."""
        kind = e.kind
        if kind == "odometry":
            robot, v, w = e.data
            return self._set_command(self._adv(s, robot, e.key[0]), robot, v, w), [], False
        if kind == "group":
            g: Group = e.data
            s = self._adv(s, g.observer, g.t)
            if self.measure_time:
                t_start = time.perf_counter()
                p_before = self.timing["predict_s"]
                s, outcomes, msgs = self._fuse_group(s, g)
                self.timing["fuse_s"] += time.perf_counter() - t_start - (self.timing["predict_s"] - p_before)
                self.timing["fuse_n"] += 1
            else:
                s, outcomes, msgs = self._fuse_group(s, g)
            for o in e.outcomes:
                self._outcome(o, -1)
            for o in outcomes:
                self._outcome(o)
            e.outcomes = outcomes
            if self.ledger is not None:
                for m in e.marks:
                    self.ledger[m] -= 1
                e.marks = [(g.observer, g.t, k, o[0]) for k, o in zip(g.keys, outcomes, strict=True)]
                for m in e.marks:
                    self.ledger[m] += 1
            return s, self._changed(e, msgs), False
        u: RdlUpdate = e.data  # a neighbour's pairwise update
        s = self._adv(s, u.receiver, u.stamp)
        if self._update_still_valid(s, e.key, u):
            return self._apply_update(s, u), [], False
        return s, [], True

    @staticmethod
    def _changed(e: Entry, msgs: list[Message]) -> list[Message]:
        """Messages a (re-)applied entry produced that differ from what it sent last time; an update it no longer
        produces (e.g. now gated) is retracted with an empty update."""
        out = []
        new = {(m.receiver, m.sub): m for m in msgs}
        for k, old in list(e.sent.items()):
            if k not in new and isinstance(old, RdlUpdate) and old.x:
                retraction = msgspec.structs.replace(old, x=(), P=())
                e.sent[k] = retraction
                out.append(retraction)
        for k, m in new.items():
            if e.sent.get(k) != m:
                e.sent[k] = m
                out.append(m)
        return out

    def _state_before(self, key: Key) -> Any:
        return self._state_at(bisect_left(self._keys, key) - 1)

    def _state_at(self, i: int) -> Any:
        """The state after entry ``i`` (the base for ``i < 0``); a run of odometry entries not computed yet (lazy)
        is computed by one :meth:`_advance_commands` call from the latest state before it."""
        if i < 0:
            return self._base
        entries = self._entries
        s = entries[i].state
        if s is not None:
            return s
        j = i - 1
        while j >= 0 and entries[j].state is None:
            j -= 1
        s = entries[j].state if j >= 0 else self._base
        run = entries[j + 1 : i + 1]
        s = self._advance_commands(s, [(e.key[0], *e.data) for e in run])
        entries[i].state = s
        return s

    def _prune(self) -> None:
        """Forget entries and served answers stamped before ``watermark - horizon`` (keeping the last as base)."""
        self._since_prune = 0
        cutoff = self._watermark - self.horizon
        n = bisect_left(self._keys, (cutoff,))
        if n > 0:
            self._base = self._state_at(n - 1)
            self._base_key = self._keys[n - 1]
            del self._entries[:n]
            del self._keys[:n]
        m = bisect_left(self._served_keys, ((cutoff,),))
        if m > 0:
            for k in self._served_keys[:m]:
                del self._served[k]
            del self._served_keys[:m]

    # ------------------------------------------------------------------------------------------------ neighbours
    def _on_query(self, q: Message) -> list[Message]:
        key: Key = (float(q.stamp), P_GROUP, q.sender, tuple(q.sub))
        answer_type = BeliefAnswer if isinstance(q, BeliefQuery) else RdlState
        why = None
        if q.receiver not in self.robots:
            why = f"robot {q.receiver} is not a robot of this node"
        elif self._t0 is None:
            why = "the node has not started"
        else:
            why = self._too_old(key[0])
        ans = None
        if why is None:
            s = self._adv(self._state_before(key), q.receiver, key[0])
            ans = self._answer(s, q)
            if ans is None:
                why = f"{self.name} does not answer {type(q).__name__}"
        if ans is None:
            return [
                answer_type(sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, found=False, reason=why)
            ]
        skey = (key, q.sender, type(q).__name__)
        old = self._served.get(skey)
        if old is None:
            i = bisect_left(self._served_keys, skey)
            self._served_keys.insert(i, skey)
        elif _same(old, ans):
            ans = old
        else:
            ans = _with_seq(ans, old.seq + 1)
        self._served[skey] = ans
        self.counts["answers_sent"] += 1
        return [ans]

    def _revise(self, after: Key) -> list[Message]:
        """Recompute served answers with keys after ``after``; send those that changed, with a higher ``seq``."""
        out: list[Message] = []
        i = bisect_right(self._served_keys, (after, math.inf))
        for skey in self._served_keys[i:]:
            key, asker, _ = skey
            old = self._served[skey]
            q_type = BeliefQuery if isinstance(old, BeliefAnswer) else RdlStateQuery
            q = q_type(sender=asker, receiver=old.sender, stamp=old.stamp, sub=old.sub)
            s = self._adv(self._state_before(key), q.receiver, key[0])
            new = self._answer(s, q)
            if new is None or _same(old, new):
                continue
            new = _with_seq(new, old.seq + 1)
            self._served[skey] = new
            self.counts["revisions_sent"] += 1
            out.append(new)
        return out

    def _refused(self, m: Message, what: str) -> bool:
        """Count and refuse a message addressed to a robot this node does not own, or whose numbers are unusable
        (:func:`~swarmloc.messages.message_problem`); True when refused."""
        if m.receiver not in self.robots:
            self._count_message_rejected(f"{what} addressed to robot {m.receiver}, not a robot of this node")
            return True
        why = message_problem(m)
        if why:
            self._count_message_rejected(why)
            return True
        return False

    def _on_answer(self, a: Message) -> list[Message]:
        key: Key = (float(a.stamp), P_GROUP, a.receiver, ())
        slot = (a.sender, tuple(a.sub))
        if self._refused(a, "answer"):
            return []
        if getattr(a, "found", False):
            self._neighbours.add(a.sender)
        g = self._pending.get(key)
        if g is not None and slot in g.answers:
            old = g.answers[slot]
            if old is not None and a.seq <= old.seq:
                self._count_message_rejected("stale or duplicate answer")
                return []
            g.answers[slot] = a
            if any(v is None for v in g.answers.values()):
                return []
            del self._pending[key]
            return self._commit_group(key, g)
        pos = bisect_left(self._keys, key)
        if pos < len(self._keys) and self._keys[pos] == key and slot in self._entries[pos].data.answers:
            old = self._entries[pos].data.answers[slot]
            if old is not None and a.seq <= old.seq:
                self._count_message_rejected("stale or duplicate answer")
                return []
            self._entries[pos].data.answers[slot] = a
            return self._recompute(pos, late=True)
        if self._too_old(key[0]):
            self._count_message_rejected("answer older than the history horizon")
        else:
            self._count_message_rejected("answer to no query of this node")
        return []

    def _on_update(self, u: RdlUpdate) -> list[Message]:
        if self._refused(u, "update"):
            return []
        key: Key = (float(u.stamp), P_GROUP, u.sender, tuple(u.sub))
        self._neighbours.add(u.sender)
        served = self._served.get((key, u.sender, "RdlStateQuery"))
        if served is None:
            self._count_message_rejected("update for a state this node never sent")
            return []
        if u.based_on != served.seq:
            self._count_message_rejected("update computed from an outdated state (stale)")
            return []
        why = self._too_old(key[0])
        if why:
            self._count_message_rejected(f"update {why}")
            return []
        return self._file_update(key, u, "update", empty=not u.x)

    def _file_update(self, key: Key, u: Message, kind: str, empty: bool) -> list[Message]:
        """File a validated update from a neighbour as a history entry of ``kind`` at ``key``: an ``empty`` one says
        the exchange is settled without an update, or retracts the update filed there; a changed one replaces it and
        replays; a duplicate is rejected."""
        pos = bisect_left(self._keys, key)
        exists = pos < len(self._keys) and self._keys[pos] == key
        if empty:  # no update (the neighbour did not fuse this exchange), or a retraction of an earlier one
            if not exists:
                self.counts["no_update"] += 1
                return []
            del self._keys[pos]
            del self._entries[pos]
            return self._recompute(pos, late=True, changed=key) if pos < len(self._entries) else self._revise(key)
        if exists:
            if self._entries[pos].data == u:
                self._count_message_rejected("duplicate update")
                return []
            self._entries[pos].data = u
            return self._recompute(pos, late=True)
        return self._insert(pos, Entry(key, kind, u))

    def _update_still_valid(self, s: Any, key: Key, u: RdlUpdate) -> bool:
        """An update applies only while the state it was computed from is still the state before its key."""
        skey = (key, u.sender, "RdlStateQuery")
        served = self._served.get(skey)
        if served is None or served.seq != u.based_on:
            return False
        q = RdlStateQuery(sender=u.sender, receiver=u.receiver, stamp=u.stamp, sub=u.sub)
        return _same(served, self._answer(s, q))


SAME_RTOL = 1e-10
"""Answers whose numbers differ by less than this (relative, at least absolute for numbers below 1) are the same:
a replay that re-derives a state along another path may change the last bits, and such a change must not start
a revision (over a network, two nodes would otherwise send each other last-bit revisions forever)."""


def _same(a: Message | None, b: Message | None) -> bool:
    """Equal apart from the revision number and last-bit differences of the numbers (:data:`SAME_RTOL`)."""
    if a is None or b is None:
        return a is b
    if type(a) is not type(b):
        return False
    for f in a.__struct_fields__:
        if f == "seq":
            continue
        x, y = getattr(a, f), getattr(b, f)
        if x == y:
            continue
        if not (isinstance(x, tuple) and isinstance(y, tuple) and len(x) == len(y)):
            return False
        for u, v in zip(x, y, strict=True):
            if abs(u - v) > SAME_RTOL * max(1.0, abs(u), abs(v)):
                return False
    return True


def _with_seq(m: Message, seq: int) -> Message:
    return msgspec.structs.replace(m, seq=seq)


def belief_answer(q: Message, b: GroupGaussian) -> BeliefAnswer:
    """The answer to a :class:`~swarmloc.messages.BeliefQuery` carrying belief ``b``."""
    return BeliefAnswer(sender=q.receiver, receiver=q.sender, stamp=q.stamp, sub=q.sub, mean=flat(b.mean),
                        cov=flat(b.cov))  # fmt: skip


def usable_covariance(C: np.ndarray) -> bool:
    """Finite and positive definite (a Cholesky factorization exists)."""
    if C.shape == (3, 3):  # leading minors of the lower triangle (what Cholesky reads), with a margin
        p00, p01, p02, p10, p11, p12, p20, p21, p22 = C.ravel().tolist()
        if all(map(math.isfinite, (p00, p01, p02, p10, p11, p12, p20, p21, p22))):
            m2 = p00 * p11 - p10 * p10
            m3 = p00 * (p11 * p22 - p21 * p21) - p10 * (p10 * p22 - p21 * p20) + p20 * (p10 * p21 - p11 * p20)
            tr = p00 + p11 + p22
            if p00 > 0 and m2 > 1e-9 * tr * tr and m3 > 1e-9 * tr * tr * tr:
                return True
    if not np.isfinite(C).all():
        return False
    try:
        np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        return False
    return True


def check_model(where: str, initial: Mapping[int, Any], noise: object) -> None:
    """Every initial belief is one SE(2) :class:`GroupGaussian` and ``noise`` a :class:`UnicycleNoise`."""
    for r, b in initial.items():
        if not isinstance(b, GroupGaussian) or b.group is not SE2 or b.batch_shape:
            raise ValueError(f"{where}: initial belief of robot {r} must be one SE(2) GroupGaussian, got {b!r}")
    if not isinstance(noise, UnicycleNoise):
        raise ValueError(f"{where}: 'noise' must be a UnicycleNoise, got {type(noise).__name__}")


class RobotNode(Node):
    """A node that estimates one robot (every distributed estimator): built from that robot's belief alone.

    Parameters
    ----------
    robot: the robot's id.
    initial: its initial belief, an SE(2) :class:`~swarmloc.gaussian.GroupGaussian` (holding at ``t0``).
    noise: process noise of its odometry (:class:`~swarmloc.motion.UnicycleNoise`).
    Other keywords: see :class:`Node`. Neighbours are learnt as they are detected; they are asked for their
    belief (:class:`~swarmloc.messages.BeliefQuery`) and never read otherwise.
    """

    def __init__(self, robot: int, initial: GroupGaussian, *, noise: UnicycleNoise, **kw: Any) -> None:
        cls = type(self).__name__
        if not isinstance(robot, int | np.integer) or isinstance(robot, bool):
            raise ValueError(f"{cls}: 'robot' must be an integer id, got {robot!r}")
        check_model(cls, {robot: initial}, noise)
        self.robot = int(robot)
        self.initial = initial
        self.noise = noise
        super().__init__((self.robot,), **kw)

    def _requests(self, g: Group) -> list[Message]:
        targets = sorted({d.target for d in g.detections if self._needs_answer(g, d)})
        return [BeliefQuery(sender=self.robot, receiver=t, stamp=g.t) for t in targets]

    def _answer(self, s: Any, q: Message) -> Message | None:
        if isinstance(q, BeliefQuery):
            return belief_answer(q, self._belief(s, q.receiver))
        return None
