"""A robot's filter as a **node**: it owns its filter state, clock, odometry commands and a bounded history.

One node class runs in every driver: the in-process runner (:mod:`swarmloc.runner`), a network process (one robot
per process) and, through the same kernels, a batched engine. A node never calls anybody: it consumes inputs with
:meth:`Node.step` and returns the messages it wants sent (queries, answers, updates), so the driver decides how
they travel (sans-I/O). It is made of parts with one job each:

* :mod:`~swarmloc.node.clock`: the present, the horizon and tolerance, jumps of the robot's clock;
* :mod:`~swarmloc.node.inputs`: what a detection and an odometry record must be, each robot's odometry timeline;
* :mod:`~swarmloc.node.intake`: the robot's own inputs checked and filed (:class:`~swarmloc.node.intake.Intake`);
* :mod:`~swarmloc.node.history`: stamped entries and the states after them;
* :mod:`~swarmloc.node.filing`: entries filed and applied, replay of late input, the horizon
  (:class:`~swarmloc.node.filing.Filing`);
* :mod:`~swarmloc.node.protocol`: which messages are accepted, answered, refused and revised
  (:class:`~swarmloc.node.protocol.Exchange`);
* :mod:`~swarmloc.node.accounting`: counters that always add up;
* :mod:`~swarmloc.node.update`: the one Kalman update with its gate (used by the filters);
* :mod:`~swarmloc.node.trust`: teammates' messages checked against what the node knows, suspects, quarantine.

**State as a function of the inputs** (keys: :mod:`~swarmloc.node.keys`). The state after a history entry is the
state after the previous one with every robot the entry involves predicted to the entry's stamp with the
command in force, then the entry applied. Hence :meth:`Node.belief_at` ``(t)`` is the belief after all entries
stamped ``<= t``, predicted to ``t``: the same whenever it is asked; a neighbour's query keyed ``q`` is answered
from the state after all entries keyed before ``q`` (two robots that detect each other at one instant get a
fixed, acyclic order); within the horizon the final state does not depend on the order the inputs came in.

**Commands.** Odometry ``(robot, t0, t1, v, w)`` sets the robot's command ``(v, w)`` from ``t0``. Past ``t1``
with no later odometry the node assumes the robot stopped (command ``(0, 0)``, the motion model's zero-speed
diffusion keeps the covariance growing) and counts it (:mod:`~swarmloc.node.inputs`).

**Parts.** The node owns its records (clock, accounting, trust) and three working parts, made with what they need:
:class:`~swarmloc.node.filing.Filing` (its own history and odometry timeline), :class:`~swarmloc.node.protocol.Exchange`
(the answers it served, the groups waiting, the neighbours) and :class:`~swarmloc.node.intake.Intake`. A part calls
the node only through its hooks (below), so an estimator's override applies wherever the part needs it.

Filters subclass :class:`Node` (one robot: :class:`~swarmloc.node.robot.RobotNode`; centralized: one node for the
team) and provide ``_initial_state``, ``_advance``, ``_set_command``, ``_fuse_group``, ``_belief`` and, where they
talk to neighbours, ``_requests``, ``_answer``, ``update_types`` and ``_apply_update``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from swarmloc.events import Detection, Kind, Odometry
from swarmloc.gaussian import GroupGaussian, world_covariance
from swarmloc.lie import SE2, SE3
from swarmloc.messages import Answer, Message, RdlUpdate, TeamUpdate
from swarmloc.node.accounting import Accounting
from swarmloc.node.associate import AssociationView, check_association, check_sensor
from swarmloc.node.clock import DEFAULT_CONFIRM, DEFAULT_HORIZON, DEFAULT_TOLERANCE, Clock
from swarmloc.node.filing import Filing
from swarmloc.node.inputs import Landmarks, brief, finite_number, landmark_state
from swarmloc.node.intake import Intake
from swarmloc.node.keys import Entry, Group, Key, Position, SubKey
from swarmloc.node.protocol import Exchange
from swarmloc.node.trust import DEFAULT_QUARANTINE, Trust
from swarmloc.node.update import Gate, Outcome
from swarmloc.text import ids, numbers, stamp

__all__ = ["Node", "Reach", "belief_of", "refusal"]


@dataclass(frozen=True, slots=True)
class Reach:
    """An input without data: the driver tells the node that nothing before ``stamp`` [s] can still come, so that it
    reaches the boundaries it planned up to there (:meth:`Node.boundary`; ``diekf``'s re-forming clusters)."""

    stamp: float


def belief_of(mean: np.ndarray, cov: np.ndarray) -> GroupGaussian:
    """A node's SE(2) belief from its filter's mean ``(3, 3)`` and covariance ``(3, 3)`` (SE(3): ``(4, 4)`` and
    ``(6, 6)``), not validated again: a
    filter state is valid by construction (every input is checked once, at the node's door, and every update's
    result is checked by :func:`~swarmloc.node.update.gated_kalman` or the filter)."""
    return GroupGaussian(SE2 if mean.shape[-1] == 3 else SE3, mean, cov, validate=False)


def refusal(d: Detection, observer: int, use_relative: bool, use_landmarks: bool) -> tuple[str, str] | None:
    """``("rejected", reason)`` of a detection by ``observer`` refused before any state is read (its kind switched
    off, a robot detection without a target or of its observer, a landmark's relative pose), or None: the node's and
    the engine's one wording (:meth:`Node._classify`)."""
    if d.kind == Kind.ABSOLUTE:
        return None
    if d.target_is_robot:
        if not use_relative:
            return ("rejected", "relative measurements are switched off")
        if d.target is None:
            return ("rejected", "robot detection without a target id")
        if d.target == observer:
            return ("rejected", "the target is the observer itself")
        return None
    if d.kind == Kind.POSE:
        return ("rejected", "a landmark is a point: it has no relative pose")
    if not use_landmarks:
        return ("rejected", "landmark measurements are switched off")
    return None


class Node:
    """Base class of every estimator's node (see the module docstring).

    Parameters common to all nodes
    ------------------------------
    t0: start time [s] of the initial belief; None: set by :meth:`start` or by the first input's stamp.
    horizon: seconds of history kept for out-of-order input and exact past answers (> 0).
    tolerance: seconds past the node's present an input may be stamped (> 0, at most ``horizon``; default: the
        horizon; :mod:`~swarmloc.node.clock`).
    jump_inputs: inputs in a row, at distinct stamps, that confirm a jump of the robot's clock.
    gate: chi-square gate probability in (0, 1) for innovations, or None (no gating).
    landmarks: known landmarks ``id -> (x, y, std_x, std_y)`` [m].
    use_relative, use_landmarks: whether detections of robots / of landmarks are fused (else rejected, counted).
    quarantine: a teammate's updates refused in a row (each failing its check on the gate) after which it is
        quarantined for the run, or None: never (:mod:`~swarmloc.node.trust`).
    association: ``tags`` (anonymous robot detections refused), ``nearest`` or ``joint``
        (:mod:`~swarmloc.node.associate`: anonymous detections are given an identity among the teammates' beliefs
        at the scan's stamp); association_gate: the chi-square probability of the association gate; sensor_range
        [m]: teammates predicted within it and given no detection of a scan are counted ``association_missed``
        (None: not counted), those within ``sensor_fov`` [rad] of the heading only when it is set (total width;
        None: all round). The node's ``_associate`` uses them (default: none).
    """

    name: ClassVar[str] = "node"
    distributed: ClassVar[bool] = True
    over_network: ClassVar[bool] = True
    """False for an estimator whose messages the network driver (:mod:`swarmloc.net.process`) cannot carry."""
    update_types: ClassVar[tuple[type[RdlUpdate] | type[TeamUpdate], ...]] = ()
    """Message types from neighbours this node files in its history (a neighbour's share of a joint update)."""
    measure_time: bool = False
    """Set True (on a node or a class) to accumulate ``timing``: seconds and counts of predictions and of
    detection-group updates (Table 6.1). Off by default: the clock calls cost about 5% of a replay."""
    lazy_odometry: ClassVar[bool] = False
    """True: the state of a command appended in order is computed only when needed, for a run of commands at once
    (:meth:`_advance_commands`); the result is the same as computing every command's state at once."""

    def __init__(
        self,
        robots: Sequence[int],
        *,
        t0: float | None = None,
        horizon: float = DEFAULT_HORIZON,
        tolerance: float | None = DEFAULT_TOLERANCE,
        jump_inputs: int = DEFAULT_CONFIRM,
        gate: float | None = None,
        landmarks: Landmarks | None = None,
        use_relative: bool = True,
        use_landmarks: bool = True,
        quarantine: int | None = DEFAULT_QUARANTINE,
        association: str = "tags",
        association_gate: float = 0.99,
        sensor_range: float | None = None,
        sensor_fov: float | None = None,
    ) -> None:
        cls = type(self).__name__
        check_association(cls, association, association_gate)
        check_sensor(cls, sensor_range, sensor_fov)
        self.association = association
        self.association_gate = float(association_gate)
        self.sensor_range = sensor_range
        self.sensor_fov = sensor_fov
        self._clock = Clock(horizon, tolerance, jump_inputs, cls)
        self.accounting = Accounting(self.name)
        try:
            self.gate = Gate(gate)
            self._trust = Trust(self.name, quarantine, self.accounting)
        except ValueError as exc:
            raise ValueError(f"{cls}: {exc}") from None
        self.robots: tuple[int, ...] = tuple(robots)
        self.landmarks = landmarks
        self.use_relative = use_relative
        self.use_landmarks = use_landmarks
        self.timing = {"predict_s": 0.0, "predict_n": 0, "fuse_s": 0.0, "fuse_n": 0}
        """With ``measure_time``: seconds and counts of predictions and of detection-group updates (net of the
        predictions inside them)."""
        self._filing = Filing(self, self.lazy_odometry, self._clock, self.accounting, self._trust)
        self._history = self._filing.history
        self._exchange = Exchange(self, self.robots, self.update_types, self._filing)
        self._intake = Intake(self, self.robots, self._filing, self._exchange)
        if t0 is not None:
            self.start(t0)

    # ------------------------------------------------------------------------------------------------ public
    @property
    def counts(self) -> Any:
        return self.accounting.counts

    @property
    def reasons(self) -> Any:
        return self.accounting.reasons

    @property
    def ledger(self) -> Any:
        return self.accounting.ledger

    @ledger.setter
    def ledger(self, value: Any) -> None:
        self.accounting.ledger = value

    def set_lazy_odometry(self, lazy: bool) -> None:
        """This node's ``lazy_odometry`` (default: its class's), before its first input: an analysis that logs each
        prediction once, in order, turns lazy runs off (:mod:`swarmloc.evaluation.observability`)."""
        if self.history_size:
            raise RuntimeError("set_lazy_odometry: the node has filed inputs; set it before the first input")
        self._filing.set_lazy(lazy)

    @property
    def started(self) -> bool:
        return self._clock.t0 is not None

    @property
    def t0(self) -> float | None:
        """Start time [s] of the initial belief (None until started)."""
        return self._clock.t0

    @property
    def horizon(self) -> float:
        return self._clock.horizon

    @property
    def tolerance(self) -> float:
        return self._clock.tolerance

    @property
    def present(self) -> float:
        """The node's present [s]: the latest stamp of an accepted input (``-inf`` before the start)."""
        return self._clock.present

    @property
    def history_size(self) -> int:
        """Entries kept in the history (about the inputs of one horizon, plus fewer than 64 not yet pruned)."""
        return len(self._history)

    @property
    def neighbours(self) -> frozenset[int]:
        """Robots this node has heard from in an accepted message (an answer that found a belief, an update)."""
        return frozenset(self._exchange.neighbours)

    @property
    def suspects(self) -> dict[int, int]:
        """``robot -> refusals counted against that teammate`` (its answers gated, its updates refused), those above
        zero (:mod:`~swarmloc.node.trust`; also in :meth:`stats` as ``suspect_<robot>``)."""
        return self._trust.suspects()

    @property
    def quarantined(self) -> frozenset[int]:
        """Teammates quarantined for the rest of the run (:mod:`~swarmloc.node.trust`)."""
        return frozenset(self._trust.quarantined)

    @property
    def pending(self) -> int:
        """Detection groups waiting for neighbours' answers."""
        return len(self._exchange.pending)

    @property
    def first_pending(self) -> Key | None:
        """Key of the earliest detection group waiting for answers (None: none waits)."""
        pending = self._exchange.pending
        return min(pending) if pending else None

    @property
    def x(self) -> np.ndarray:
        """``(x [m], y [m], theta [rad])`` of every robot of the node at its present, robots in id order, ``(3 n,)``
        (a read-only copy; filterpy's ``x``).

        The present is the stamp of the latest input the node has filed. An odometry record is filed at its start
        ``t0`` (its command is in force from then on: the node does not take the time to have passed to ``t1``
        until a later input says so), and a detection that waits for a teammate's answer is filed once the answer
        is in. So after ``node.step(Odometry(0, 0.0, 0.5, 0.4, 0.1))`` alone the present is 0.0 and ``x`` the
        start pose. The pose at any time ``t`` of the history is ``node.belief(t)`` (predicted with the command
        in force; ``swarmloc.world_covariance(b.mean, b.cov)`` gives it as ``(x, P)``).
        ``examples/node_snippet.py`` shows both."""
        return self._frozen_joint()[0]

    @property
    def P(self) -> np.ndarray:
        """The covariance of :attr:`x` ``(3 n, 3 n)``: world frame, first order (a read-only copy; filterpy's ``P``;
        :func:`swarmloc.gaussian.world_covariance` of the beliefs, with the cross-covariances a centralized
        filter keeps)."""
        return self._frozen_joint()[1]

    def __repr__(self) -> str:
        """Class, robot(s), estimator name, present [s] and :attr:`x` (at most 9 numbers; the rest counted)."""
        who = f"robot={self.robots[0]}" if len(self.robots) == 1 else f"robots={ids(self.robots)}"
        head = f"{type(self).__name__}({who}, estimator={self.name!r}"
        if self._clock.t0 is None:
            return f"{head}, not started)"
        try:
            x = numbers(self.x)
        except (ValueError, KeyError, ArithmeticError, np.linalg.LinAlgError) as exc:  # a repr never raises
            x = f"? ({type(exc).__name__})"
        return f"{head}, present={stamp(self.present)}, x={x})"

    def _frozen_joint(self) -> tuple[np.ndarray, np.ndarray]:
        x, P = self._joint(self._present_or_start())
        x, P = np.array(x, dtype=float), np.array(P, dtype=float)
        x.setflags(write=False)
        P.setflags(write=False)
        return x, P

    def _joint(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(x, P)`` of every robot at ``t`` in world-frame ``(x, y, theta)``; the default knows no
        cross-covariances (a distributed node holds one robot)."""
        parts = [world_covariance(b.mean, b.cov) for b in (self.belief_at(t, r) for r in self.robots)]
        x = np.concatenate([xk for xk, _ in parts])
        P = np.zeros((x.size, x.size))
        for k, (_, Pk) in enumerate(parts):
            P[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = Pk
        return x, P

    def start(self, t0: float) -> None:
        """Set the time [s] at which the initial belief holds (once)."""
        if not finite_number(t0):  # (an int too large for a float too: math.isfinite would raise on it)
            raise ValueError(f"{type(self).__name__}.start: t0 must be a finite time in seconds, got {brief(t0)}")
        if self._clock.t0 is not None:
            if float(t0) != self._clock.t0:
                raise ValueError(f"{type(self).__name__}.start: already started at t0 = {self._clock.t0}, got {t0}")
            return
        self._clock.start(t0)
        self._history.reset(self._initial_state(float(t0)), (float(t0), -1, -1, ()))

    def step(self, item: Odometry | Detection | Iterable[Detection] | Message) -> list[Message]:
        """Consume one input (odometry, one or several detections, or a message from a neighbour) and return the
        messages to send. Never raises on bad data: it is refused and counted (``counts``, ``reasons``)."""
        if isinstance(item, Odometry):
            return self._intake.on_odometry(item)
        if isinstance(item, Detection):
            return self._intake.on_detections([item])
        if isinstance(item, Message):
            return self._exchange.on_message(item)
        if isinstance(item, Reach):  # (a node with boundaries takes it first: nothing else to do)
            return []
        if isinstance(item, Iterable) and not isinstance(item, str | bytes):
            items = list(item)
            if items and all(isinstance(d, Detection) for d in items):
                return self._intake.on_detections(items)
        self.counts["messages"] += 1
        self.accounting.message_rejected(f"unsupported input of type {type(item).__name__}")
        return []

    def plan(self, events: Iterable[Any]) -> None:
        """The whole team's recorded events, known before the run (drivers of a recording give them before the first
        input; a live one does not): an estimator may plan from them (``diekf``'s re-forming clusters). Default:
        nothing."""

    def boundary(self) -> float | None:
        """The next stamp [s] of its plan (:meth:`plan`) the node must reach before it takes what is stamped after it:
        a driver steps it with :class:`Reach` once nothing before that stamp can still come (None: none; default)."""
        return None

    def awaits(self, t: float) -> str | None:
        """What the node still waits for from its teammates for its boundaries up to ``t`` [s] (None: nothing;
        default): a driver holds its detection groups stamped ``t`` until then."""
        return None

    def belief_at(self, t: float, robot: int | None = None) -> GroupGaussian:
        """Belief of ``robot`` (default: the node's own) at time ``t`` [s]: after every entry stamped ``<= t``,
        predicted to ``t`` with the command in force then. Raises ValueError for ``t`` before the kept history."""
        robot = self._robot_arg(robot)
        if self._clock.t0 is None:
            raise ValueError(f"{type(self).__name__}.belief_at: the node has not started (no input yet, no t0)")
        base_key = self._history.base_key
        if base_key is None or not t >= base_key[0]:
            raise ValueError(
                f"{type(self).__name__}.belief_at: t = {t} is before the kept history (from "
                f"{None if base_key is None else base_key[0]}); the horizon is {self.horizon} s"
            )
        at: Key = (t, 3, 0, ())
        s = self._history.state_before(at)
        return self._belief(self._adv(s, robot, t, at), robot)

    def belief(self, t: float | None = None, robot: int | None = None) -> GroupGaussian:
        """Belief of ``robot`` at ``t`` [s] (default: the node's present)."""
        return self.belief_at(self._present_or_start() if t is None else t, robot)

    def stats(self) -> dict[str, int]:
        """Counters, every key present: ``detections == fused + gated + rejected + unknown + pending`` and
        ``odometry == odometry_used + odometry_rejected + odometry_pending`` at all times
        (:mod:`~swarmloc.node.accounting`)."""
        held_det = sum(len(x) for _, _, x in self._clock.held if isinstance(x, list))
        held_odo = sum(1 for _, _, x in self._clock.held if isinstance(x, Odometry))
        pending = sum(len(g.detections) for g in self._exchange.pending.values()) + held_det
        return self.accounting.stats(pending, held_odo)

    def expire(self, before: float | None = None) -> list[Message]:
        """Give up waiting for answers to groups stamped before ``before`` (default: all; their detections still
        missing an answer end ``unknown``, "no answer"); with no ``before`` (the end of a run) inputs held as a
        possible clock jump are refused too. Drivers call it on a timeout or at the end."""
        out: list[Message] = []
        if before is None:
            self._intake.refuse_held(self._clock.release())
        pending = self._exchange.pending
        for key in sorted(pending):
            if before is None or key[0] < before:
                out += self._filing.commit_group(key, pending.pop(key))
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
        """State after a run of command entries ``cmds = [(t [s], robot, v [m/s], w [rad/s]), ...]`` (key order):
        each robot predicted to ``t``, then its command set. A filter may override it with a faster equivalent
        (the same result to rounding: tests/test_node.py checks every estimator); the default applies
        :meth:`_advance` and :meth:`_set_command` one by one."""
        for t, robot, v, w in cmds:
            s = self._set_command(self._filing.timed_advance(s, robot, t), robot, v, w)
        return s

    def _fuse_group(self, s: Any, g: Group) -> tuple[Any, list[Outcome], list[Message]]:
        """Apply a complete detection group to ``s`` (the observer already predicted to ``g.t``)."""
        raise NotImplementedError

    def _belief(self, s: Any, robot: int) -> GroupGaussian:
        raise NotImplementedError

    def _requests(self, g: Group) -> list[Message]:
        """Queries a group needs before it can be applied (default: none)."""
        return []

    def _answer(self, s: Any, q: Message) -> Answer | None:
        """Answer a query from state ``s`` (predicted to the query's stamp); None: this node does not answer it."""
        return None

    def _update_problem(self, u: Message) -> str | None:
        """Why a neighbour's update (one of :attr:`update_types`) cannot be filed, or None."""
        return None

    def _update_lie(self, u: Message) -> str | None:
        """Why a neighbour's update (filable) cannot be what a teammate with this node's gate sent: the reason it is
        refused and counted against its sender (:mod:`~swarmloc.node.trust`), or None (default: no check)."""
        return None

    def _apply_update(self, s: Any, u: Message) -> tuple[Any, bool]:
        """``(state after a neighbour's update, True)``, or ``(state, False)`` when the update no longer applies
        (the entry becomes void)."""
        raise NotImplementedError

    def _placeholder(self, data: Any) -> bool:
        """Whether a history entry's ``data`` stands for an update not received yet (filed by the estimator when it
        answers, e.g. :class:`~swarmloc.estimators.rdl.Unconfirmed`; counted ``updates_missing`` until replaced or
        removed; default: none does)."""
        return False

    def _on_query(self, q: Message) -> list[Message]:
        """Answer a neighbour's query (:meth:`~swarmloc.node.protocol.Exchange.on_query`; an estimator may extend
        it)."""
        return self._exchange.on_query(q)

    def _revise(self, after: Key) -> list[Message]:
        """The answers given to queries keyed after ``after`` that changed, revised
        (:meth:`~swarmloc.node.protocol.Exchange.revise`; an estimator may extend it)."""
        return self._exchange.revise(after)

    def _prune(self) -> None:
        """Forget entries, answers given and odometry intervals stamped before ``present - horizon`` (every
        :data:`~swarmloc.node.history.PRUNE_EVERY` inputs; an estimator may extend it)."""
        cutoff = self._clock.present - self.horizon
        self._filing.prune(cutoff)
        self._exchange.prune(cutoff)

    def _restamp(self, s: Any, t: float) -> Any:
        """The state ``s`` with every robot's clock set to ``t`` (after a jump of the robot's clock)."""
        stamps = s.t
        return s._replace(t=tuple(t for _ in stamps) if isinstance(stamps, tuple) else t)

    def _settle(self, g: Group) -> list[Message]:
        """Messages that close the exchanges a group with identities given (``g``) asked for and did not use (a
        teammate asked about an anonymous detection given another robot: ``rdl``'s "no update"; default: none)."""
        return []

    def _associate(self, s: Any, g: Group) -> AssociationView | None:
        """The group with identities given to its anonymous robot detections (the observer predicted to ``g.t`` in
        ``s``), or None to fuse it as it is (default: a node without an association policy;
        :mod:`~swarmloc.node.associate`)."""
        return None

    # ------------------------------------------------------------------------------------------------ targets
    def _needs_answer(self, g: Group, d: Detection) -> bool:
        """True when fusing ``d`` needs the target robot's answer (distributed nodes)."""
        return (
            d.kind != Kind.ABSOLUTE and d.target_is_robot and self.use_relative and d.target is not None
            and d.target != g.observer
        )  # fmt: skip

    def _classify(self, g: Group, d: Detection, sub: SubKey = ()) -> tuple[str, Any]:
        """What ``d`` is of: ``("absolute", None)``, ``("robot", answer)``, ``("landmark", (p, C))``, or the outcome
        ``("rejected" | "unknown", reason)`` when it cannot be fused."""
        if d.kind == Kind.ABSOLUTE:
            return (Kind.ABSOLUTE, None)
        why = refusal(d, g.observer, self.use_relative, self.use_landmarks)
        if why is not None:
            return why
        if d.target_is_robot:
            return self._robot_target(g, d, sub)
        lm = landmark_state(self.landmarks, d.target)
        if lm is None:
            return ("unknown", f"landmark {d.target} is not in the map")
        return ("landmark", lm)

    def _fuse_each(self, x: Any, g: Group, fuse: Callable[[Any, Detection, tuple[str, Any]], tuple[Any, Outcome]]
                   ) -> tuple[Any, list[Outcome]]:  # fmt: skip
        """Group ``g``'s detections fused into ``x`` (a state, or the part of it an update changes) one at a time, in
        order: each classified (:meth:`_classify`; a rejected or unknown one counted so), then ``fuse(x, d, target)``
        gives the new ``x`` and the detection's outcome. Returns the last ``x`` and the outcomes."""
        outcomes: list[Outcome] = []
        for d in g.detections:
            target = self._classify(g, d)
            if target[0] in ("rejected", "unknown"):
                outcomes.append(target)
                continue
            x, out = fuse(x, d, target)
            outcomes.append(out)
        return x, outcomes

    def _robot_target(self, g: Group, d: Detection, sub: SubKey) -> tuple[str, Any]:
        """A distributed node knows a neighbour only from its answer."""
        a = None if d.target is None else g.answers.get((d.target, sub))
        if a is None:
            return ("unknown", f"no answer from robot {d.target}")
        if not a.found:
            return ("unknown", f"robot {d.target}: {a.reason}")
        return ("robot", a)

    def _gated(self, nis: float, m: int) -> Outcome | None:
        """The gate's verdict on a normalized innovation squared ``nis`` of dimension ``m`` (None: it passes)."""
        return self.gate.verdict(nis, m)

    def _robot_arg(self, robot: int | None) -> int:
        if robot is None:
            if len(self.robots) != 1:
                raise ValueError(f"{type(self).__name__}: say which robot ({list(self.robots)})")
            return self.robots[0]
        if robot not in self.robots:
            raise KeyError(f"{type(self).__name__}: unknown robot id {robot!r} (this node has {list(self.robots)})")
        return robot

    def _present_or_start(self) -> float:
        if self._clock.t0 is None:
            raise ValueError(f"{type(self).__name__}: the node has not started (no input yet, no t0)")
        return self._clock.present

    # ------------------------------------------------------------------------------------------------ parts
    def _adv(self, s: Any, robot: int, t: float, after: Position | None = None) -> Any:
        """``s``, the state after the entries keyed before ``after`` (default: the entry being applied), with
        ``robot`` predicted to ``t``; past the end of the odometry interval in force the robot is stopped there
        (:meth:`~swarmloc.node.filing.Filing.adv`)."""
        return self._filing.adv(s, robot, t, after)

    def _file(self, entries: list[Entry], accept: bool = True) -> list[Message]:
        """Put new entries into the history and apply them (:meth:`~swarmloc.node.filing.Filing.file`)."""
        return self._filing.file(entries, accept)
