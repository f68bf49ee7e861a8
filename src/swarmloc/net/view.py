"""A live view of a team through Foxglove's SDK (``foxglove-sdk``): a WebSocket server for Foxglove Studio and an
MCAP recording (the ROS 2 bag format), fed with what ``swarmloc team`` collects.

:class:`TeamView` logs, on the data clock (log time = stamp in ns):

* ``/swarmloc/beliefs`` (JSON): every belief a robot publishes: ``robot, stamp, rev, final, x, y, theta`` [m, rad],
  ``cov`` (9 numbers, exponential coordinates, row-major) and ``ellipse``: the 95% position ellipse of its
  ``(x, y)`` marginal, 24 world points [m];
* ``/swarmloc/truth`` (JSON, where the source has ground truth): ``robot, stamp, x, y, theta`` at each final belief;
* ``/swarmloc/detections`` (JSON): each detection of the source, ``observer, target, stamp, kind, z``, logged once the
  observer's final belief has passed its stamp, with ``at``: where it puts the target (world [m], by the
  observer's belief; None for a kind without a position);
* ``/swarmloc/map`` (JSON): the fused line map (:class:`~swarmloc.net.server.MapStore` of every robot's
  :class:`~swarmloc.net.schema.Lines`, the belief server's fusion), ``lines`` as ``rho, alpha, cov, ends, robots,
  n_obs``, at most every ``map_every`` s of wall time and at :meth:`close`; or the belief server's own answer,
  given to :meth:`show_map` (``swarmloc node --view``: the node asks the server for it);
* ``/swarmloc/scene`` (``foxglove.SceneUpdate``, Foxglove's 3D panel): per robot an arrow at its belief, its
  covariance ellipse and its true pose; the map's lines.

Open it live in Foxglove Studio ("Open connection", Foxglove WebSocket, ``ws://127.0.0.1:<port>``), or open the
MCAP file afterwards.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.events import Detection
from swarmloc.lie import SE2
from swarmloc.net.schema import Belief, Lines, MapAnswer
from swarmloc.net.server import MapStore

__all__ = ["TOPICS", "TeamView", "ellipse"]

TOPICS = ("/swarmloc/beliefs", "/swarmloc/truth", "/swarmloc/detections", "/swarmloc/map", "/swarmloc/scene")
CHI2_95_2DOF = 5.991464547107979


def ellipse(mean_xy: np.ndarray, cov_xy: np.ndarray, n: int = 24, chi2: float = CHI2_95_2DOF) -> np.ndarray:
    """``n`` points ``(n, 2)`` [m] of the ellipse ``{p: (p - m)^T C^-1 (p - m) = chi2}`` (95% for 2 dof)."""
    w, V = np.linalg.eigh(0.5 * (cov_xy + cov_xy.T))
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return mean_xy + (np.stack([np.cos(a), np.sin(a)], -1) * np.sqrt(np.maximum(w, 0) * chi2)) @ V.T


def _target_at(d: Detection, g: np.ndarray) -> list[float] | None:
    """Where detection ``d`` puts its target in the world, seen from observer pose ``g`` (SE(2) matrix)."""
    z = np.asarray(d.z, dtype=float)
    if d.kind == "pose":
        p = z[:2]
    elif d.kind == "range_bearing":
        p = z[0] * np.array([np.cos(z[1]), np.sin(z[1])])
    else:
        return None
    return (g[:2, :2] @ p + g[:2, 2]).tolist()


class TeamView:
    """Foxglove WebSocket server on ``host:port`` (None: none; 0: a free port, :attr:`port`) and/or an MCAP
    recording at ``mcap`` (None: none). ``truth(robot, times)``: ground truth (evaluator side; None: none);
    ``detections``: the source's events (its detections are shown). Feed it with :meth:`observe`; :meth:`close`."""

    def __init__(
        self,
        *,
        port: int | None = 8765,
        host: str = "127.0.0.1",
        mcap: str | Path | None = None,
        truth: Any = None,
        detections: Iterable[Any] = (),
        roster: Sequence[int] | None = None,
        map_every: float = 0.5,
        name: str = "swarmloc team",
    ) -> None:
        import foxglove
        from foxglove.channels import SceneUpdateChannel

        if port is None and mcap is None:
            raise ValueError("TeamView: give a port for the live view, an MCAP path to record, or both")
        self.ctx = foxglove.Context()
        self.subscriptions = 0
        view = self

        class _Listener(foxglove.ServerListener):
            def on_subscribe(self, client: Any, channel: Any) -> None:
                view.subscriptions += 1

            def on_unsubscribe(self, client: Any, channel: Any) -> None:
                view.subscriptions -= 1

        self._lock = threading.Lock()
        self.mcap = None if mcap is None else foxglove.open_mcap(str(mcap), allow_overwrite=True, context=self.ctx)
        self.server = None
        if port is not None:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.ctx,
                                                server_listener=_Listener())  # fmt: skip
        self.port = None if self.server is None else self.server.port
        obj = {"type": "object"}
        self.ch = {t: foxglove.Channel(t, message_encoding="json", schema=obj, context=self.ctx) for t in TOPICS[:4]}
        self.scene = SceneUpdateChannel(TOPICS[4], context=self.ctx)
        self.truth = truth
        self.maps = MapStore(roster)
        self.map_every = map_every
        self._map_logged = -math.inf
        self._map_dirty = False
        self._server_map = False  # a map from the belief server was shown: the own lines' map no longer is
        self._last_t = 0.0
        self._det: dict[int, list[Detection]] = {}
        for e in detections:
            if isinstance(e, Detection):
                self._det.setdefault(e.observer, []).append(e)
        for v in self._det.values():
            v.sort(key=lambda d: d.t)
        self._det_i: Counter[int] = Counter()
        self.counts: Counter[str] = Counter()
        """Messages logged per topic."""

    @property
    def url(self) -> str | None:
        """The WebSocket URL to open in Foxglove Studio (None without a live server)."""
        return None if self.port is None else f"ws://127.0.0.1:{self.port}"

    def _log(self, topic: str, msg: dict[str, Any], t: float) -> None:
        self.ch[topic].log(json.dumps(msg), log_time=max(0, int(round(t * 1e9))))
        self.counts[topic] += 1

    def observe(self, body: Any) -> None:
        """Show a collected :class:`Belief` or :class:`Lines` (anything else is ignored). Thread-safe."""
        with self._lock:
            if isinstance(body, Belief):
                self._belief(body)
            elif isinstance(body, Lines) and self.maps.store(body) and not self._server_map:
                self._map_dirty = True
            if self._map_dirty and time.monotonic() - self._map_logged >= self.map_every:
                self._log_map()

    def _belief(self, b: Belief) -> None:
        g = np.reshape(b.mean, (3, 3))
        cov = np.reshape(b.cov, (3, 3))
        x, y, th = (float(v) for v in SE2.to_xytheta(g))
        R = g[:2, :2]
        cxy = R @ cov[:2, :2] @ R.T  # the position block, rotated into the world (right perturbation)
        ell = ellipse(np.array([x, y]), cxy)
        self._last_t = max(self._last_t, b.stamp)
        msg = {"robot": b.robot, "stamp": b.stamp, "rev": b.rev, "final": b.final, "x": x, "y": y, "theta": th,
               "cov": list(b.cov), "ellipse": ell.tolist()}  # fmt: skip
        self._log("/swarmloc/beliefs", msg, b.stamp)
        true = None
        if b.final and self.truth is not None:
            try:
                true = np.asarray(self.truth(b.robot, np.array([b.stamp])), dtype=float).reshape(3)
            except ValueError:
                true = None
            if true is not None:
                self._log("/swarmloc/truth", {"robot": b.robot, "stamp": b.stamp, "x": float(true[0]),
                                              "y": float(true[1]), "theta": float(true[2])}, b.stamp)  # fmt: skip
        if b.final:
            dets, i = self._det.get(b.robot, []), self._det_i[b.robot]
            while i < len(dets) and dets[i].t <= b.stamp:
                d = dets[i]
                self._log("/swarmloc/detections", {"observer": d.observer, "target": d.target, "stamp": d.t,
                                                   "kind": d.kind, "z": [float(v) for v in d.z],
                                                   "at": _target_at(d, g)}, d.t)  # fmt: skip
                i += 1
            self._det_i[b.robot] = i
        self._scene_robot(b.robot, b.stamp, g, ell, true)

    def _scene_robot(self, r: int, t: float, g: np.ndarray, ell: np.ndarray, true: np.ndarray | None) -> None:
        from foxglove.messages import (
            ArrowPrimitive,
            Color,
            LinePrimitive,
            LinePrimitiveLineType,
            Point3,
            Pose,
            Quaternion,
            SceneEntity,
            SceneUpdate,
            Timestamp,
            Vector3,
        )

        def pose(x: float, y: float, th: float) -> Pose:
            return Pose(position=Vector3(x=x, y=y, z=0.0),
                        orientation=Quaternion(x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2)))  # fmt: skip

        ts = Timestamp(int(t), int(round((t % 1) * 1e9)) % 1_000_000_000)
        x, y, th = (float(v) for v in SE2.to_xytheta(g))
        blue, green = Color(r=0.1, g=0.4, b=1.0, a=1.0), Color(r=0.1, g=0.8, b=0.2, a=1.0)
        arrows = [ArrowPrimitive(pose=pose(x, y, th), shaft_length=0.2, shaft_diameter=0.04, head_length=0.08,
                                 head_diameter=0.1, color=blue)]  # fmt: skip
        if true is not None:
            arrows.append(ArrowPrimitive(pose=pose(*map(float, true)), shaft_length=0.2, shaft_diameter=0.04,
                                         head_length=0.08, head_diameter=0.1, color=green))  # fmt: skip
        loop = LinePrimitive(type=LinePrimitiveLineType.LineLoop, thickness=0.02, color=blue,
                             points=[Point3(x=float(px), y=float(py)) for px, py in ell])  # fmt: skip
        ent = SceneEntity(timestamp=ts, frame_id="world", id=f"robot{r}", arrows=arrows, lines=[loop])
        self.scene.log(SceneUpdate(entities=[ent]), log_time=max(0, int(round(t * 1e9))))
        self.counts[TOPICS[4]] += 1

    def show_map(self, answer: MapAnswer) -> None:
        """Show the belief server's map ``answer`` (a node's view: the team's fused map, which from then on replaces
        the map of the lines given to :meth:`observe`). Thread-safe."""
        with self._lock:
            self._server_map = True
            self._map_dirty = False
            self._log_map(answer)

    def _log_map(self, answer: MapAnswer | None = None) -> None:
        from foxglove.messages import Color, LinePrimitive, LinePrimitiveLineType, Point3, SceneEntity, SceneUpdate

        ans = self.maps.answer() if answer is None else answer
        lines = [{"rho": fl.line[0], "alpha": fl.line[1], "cov": list(fl.line[2:5]), "ends": list(fl.line[5:9]),
                  "robots": list(fl.robots), "n_obs": fl.n_obs} for fl in ans.lines]  # fmt: skip
        self._log("/swarmloc/map", {"lines": lines, "observations": ans.observations, "messages": ans.messages},
                  self._last_t)  # fmt: skip
        pts = [Point3(x=e[i], y=e[i + 1]) for ln in lines for e in [ln["ends"]] for i in (0, 2)]
        black = Color(r=0.0, g=0.0, b=0.0, a=1.0)
        prim = LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=0.03, color=black, points=pts)
        ent = SceneEntity(frame_id="world", id="map", lines=[prim])
        self.scene.log(SceneUpdate(entities=[ent]), log_time=max(0, int(round(self._last_t * 1e9))))
        self.counts[TOPICS[4]] += 1
        self._map_logged = time.monotonic()
        self._map_dirty = False

    def flush(self) -> None:
        """Log the map now if lines came since it was last logged."""
        with self._lock:
            if self._map_dirty:
                self._log_map()

    def close(self) -> None:
        """Log the final map (:meth:`flush`), finish the MCAP file and stop the server."""
        self.flush()
        with self._lock:
            if self.mcap is not None:
                self.mcap.close()
                self.mcap = None
            if self.server is not None:
                self.server.stop()
                self.server = None

    def __enter__(self) -> TeamView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
