"""A live view of a team for Foxglove and Lichtblick, and its MCAP recording: ROS 2 messages, one set of channels.

:class:`TeamView` turns what ``swarmloc team`` (or one ``swarmloc node``) collects into ROS 2 messages (CDR with
``ros2msg`` schemas, frame ``map``, Jazzy definitions from rosbags' typestore) and hands every message, the same
bytes, to the live server (:class:`~swarmloc.net.foxglove_ws.FoxgloveServer`) and to the MCAP file. The channels
are defined here once, :data:`CHANNELS` and :data:`ROBOT_CHANNELS`, with the methods that build their messages:

* ``/tf`` (``tf2_msgs/msg/TFMessage``): ``map -> robot<r>`` at every belief (its mean);
* ``/swarmloc/robot<r>/pose`` (``geometry_msgs/msg/PoseWithCovarianceStamped``): every belief of robot ``r``,
  the covariance in ROS's world-frame convention (:func:`swarmloc.net.ros.pose_message`);
* ``/swarmloc/beliefs`` (``visualization_msgs/msg/MarkerArray``): per robot an arrow at its belief, its 95%
  position ellipse (24 points, closed) and a label; markers ``ns`` ``belief`` / ``ellipse`` / ``label``, id ``r``;
* where the source has ground truth (the evaluator's side): ``/swarmloc/robot<r>/truth``
  (``geometry_msgs/msg/PoseStamped``) and ``/swarmloc/truth`` (green arrows, ``ns`` ``truth``) at each final
  belief, and ``/swarmloc/nees`` (``geometry_msgs/msg/Vector3Stamped``, given ``score``): ``header.frame_id``
  ``robot<r>``, ``vector`` = (NEES of the final belief against truth, 3 dof; position error [m]; heading error
  [rad]) as :func:`swarmloc.evaluation.metrics.errors` computes them;
* ``/swarmloc/detections`` (MarkerArray): each detection of the source once the observer's final belief has passed
  its stamp, an arrow from the observer to where the detection puts the target (kinds with a position), 1 s life;
* ``/swarmloc/map`` (MarkerArray, ``ns`` ``map``): the fused line map as a line list (the belief server's fusion,
  :class:`~swarmloc.net.server.MapStore`, at most every ``map_every`` s of wall time and at the end), or the
  belief server's own answer given to :meth:`TeamView.show_map` (``swarmloc node --view``).

Why ROS 2 messages for everything: Foxglove, Lichtblick, rviz2 and ``ros2 bag play`` all read them, live and
recorded alike, so one layout (:data:`LAYOUT`) serves the live view and the file. rosbag2 refuses a bag whose
topics mix serialization formats, so a JSON or protobuf channel beside them would make ``ros2 bag play`` refuse
the whole recording. foxglove-sdk is therefore not used: its server refuses ``foxglove.websocket.v1`` clients
(:mod:`swarmloc.net.foxglove_ws` says why), and its typed messages are Foxglove's own schemas; rosbags already
gives swarmloc the ROS types, their definitions and CDR (:mod:`swarmloc.net.ros`), the ``mcap`` library writes
the file (profile ``ros2``).

Stamps: header stamps and log times are ROS times, ``data stamp + epoch`` [s]. A recorded or simulated source's
data clock starts at 0, so ``epoch`` is by default the view's start wall time rounded down to a whole second (the
data's fractions stay exact); a live source's stamps are Unix times already (``epoch=0``). The epoch is written
in the MCAP metadata record ``swarmloc`` (``epoch``) and the server's ``serverInfo`` metadata.
"""

from __future__ import annotations

import importlib
import logging
import math
import re
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from contextlib import suppress
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.events import Detection, Kind
from swarmloc.gaussian import symmetric
from swarmloc.net import ros
from swarmloc.net.schema import Belief, Lines, MapAnswer
from swarmloc.net.server import MapStore
from swarmloc.net.timeouts import wait_event
from swarmloc.runner import RobotTrack

__all__ = ["CHANNELS", "LAYOUT", "ROBOT_CHANNELS", "VIEW_EXTRA", "TeamView", "ViewUnavailable", "channel_type",
           "ellipse", "require_view", "robot_topic"]  # fmt: skip

log = logging.getLogger(__name__)

MARKERS = "visualization_msgs/msg/MarkerArray"
CHANNELS: dict[str, str] = {
    "/tf": "tf2_msgs/msg/TFMessage",
    "/swarmloc/beliefs": MARKERS,
    "/swarmloc/truth": MARKERS,
    "/swarmloc/nees": "geometry_msgs/msg/Vector3Stamped",
    "/swarmloc/detections": MARKERS,
    "/swarmloc/map": MARKERS,
}
"""The team's channels: topic -> ROS 2 message type."""
ROBOT_CHANNELS: dict[str, str] = {"pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
                                  "truth": "geometry_msgs/msg/PoseStamped"}  # fmt: skip
"""Each robot's channels ``/swarmloc/robot<r>/<name>``: name -> ROS 2 message type."""
LAYOUT = Path(__file__).with_name("foxglove_layout.json")
"""The Foxglove/Lichtblick layout shipped with swarmloc (3D panel, NEES and error plots of these channels)."""
VIEW_EXTRA = "pip install 'swarmloc[view]'"
CHI2_95_2DOF = 5.991464547107979
DETECTION_LIFE = 1.0  # [s] a detection arrow's marker lifetime
_ROBOT_TOPIC = re.compile(r"^/swarmloc/robot(\d+)/(\w+)$")
_BLUE, _GREEN, _ORANGE, _GREY = (0.1, 0.4, 1.0, 1.0), (0.1, 0.8, 0.2, 1.0), (1.0, 0.6, 0.1, 0.9), (0.6, 0.6, 0.6, 1.0)
_ARROW, _LINE_STRIP, _LINE_LIST, _TEXT = 0, 4, 5, 9
_ADD, _DELETE = 0, 2


class ViewUnavailable(RuntimeError):
    """The live view or the recording was asked for without the ``view`` extra installed."""


def require_view(live: bool, record: bool) -> None:
    """Raise :class:`ViewUnavailable` (one line naming ``pip install 'swarmloc[view]'``) unless the libraries of
    a live view (``websockets``) and of a recording (``mcap``) are importable, as far as they are asked for."""
    for wanted, module in ((live, "websockets"), (record, "mcap")):
        if wanted:
            try:
                importlib.import_module(module)
            except ImportError:
                raise ViewUnavailable(f"--view and --record need the 'view' extra (the {module} package is "
                                      f"missing): {VIEW_EXTRA}") from None  # fmt: skip


def robot_topic(robot: int, name: str) -> str:
    """``/swarmloc/robot<robot>/<name>`` (``name`` in :data:`ROBOT_CHANNELS`)."""
    return f"/swarmloc/robot{int(robot)}/{name}"


def channel_type(topic: str) -> str:
    """The ROS 2 message type of a view channel; ValueError for a topic the view does not publish."""
    if topic in CHANNELS:
        return CHANNELS[topic]
    m = _ROBOT_TOPIC.match(topic)
    if m is None or m.group(2) not in ROBOT_CHANNELS:
        raise ValueError(f"{topic!r} is not a channel of the view")
    return ROBOT_CHANNELS[m.group(2)]


def ellipse(mean_xy: np.ndarray, cov_xy: np.ndarray, n: int = 24, chi2: float = CHI2_95_2DOF) -> np.ndarray:
    """``n`` points ``(n, 2)`` [m] of the ellipse ``{p: (p - m)^T C^-1 (p - m) = chi2}`` (95% for 2 dof)."""
    w, V = np.linalg.eigh(symmetric(cov_xy))
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return mean_xy + (np.stack([np.cos(a), np.sin(a)], -1) * np.sqrt(np.maximum(w, 0) * chi2)) @ V.T


def _target_at(d: Detection, g: np.ndarray) -> np.ndarray | None:
    """Where detection ``d`` puts its target in the world, seen from observer pose ``g`` (SE(2) matrix)."""
    z = np.asarray(d.z, dtype=float)
    if d.kind == Kind.POSE:
        p = z[:2]
    elif d.kind == Kind.RANGE_BEARING:
        p = z[0] * np.array([np.cos(z[1]), np.sin(z[1])])
    else:
        return None
    return g[:2, :2] @ p + g[:2, 2]


def _types() -> Any:
    return ros.typestore().types


class TeamView:
    """Live server on ``host:port`` (None: none; 0: a free port, :attr:`port`) and/or an MCAP recording at
    ``mcap`` (None: none). ``truth(robot, times) -> (n, 3)``: ground truth (evaluator side; None: none);
    ``score(RobotTrack) -> {"nees", "pos", "heading"}`` (:func:`swarmloc.evaluation.metrics.errors`; with truth,
    the ``/swarmloc/nees`` channel); ``detections``: the source's events (its detections are shown); ``roster``:
    the robots (their channels are advertised from the start; others when first seen); ``epoch`` [s]: added to
    data stamps (None: this start's wall time, whole seconds); ``history``: messages per channel a late client
    is sent. Feed it with :meth:`observe`; :meth:`end_recording` finishes the file, :meth:`close` everything."""

    def __init__(
        self,
        *,
        port: int | None = 8765,
        host: str = "127.0.0.1",
        mcap: str | Path | None = None,
        truth: Callable[[int, np.ndarray], np.ndarray] | None = None,
        score: Callable[[RobotTrack], dict[str, np.ndarray]] | None = None,
        detections: Iterable[Any] = (),
        roster: Sequence[int] | None = None,
        map_every: float = 0.5,
        name: str = "swarmloc team",
        epoch: float | None = None,
        history: int = 10_000,
    ) -> None:
        if port is None and mcap is None:
            raise ValueError("TeamView: give a port for the live view, an MCAP path to record, or both")
        require_view(port is not None, mcap is not None)
        self.epoch = float(math.floor(time.time())) if epoch is None else float(epoch)
        if not (math.isfinite(self.epoch) and self.epoch >= 0):
            raise ValueError(f"TeamView: epoch must be a finite time >= 0 s, got {epoch!r}")
        self.truth, self.score = truth, score
        self.maps = MapStore(roster)
        self.map_every = map_every
        self.counts: Counter[str] = Counter()
        """Messages published per topic."""
        self.refused: Counter[str] = Counter()
        """Beliefs not shown, by reason."""
        self._lock = threading.RLock()
        self._closed = threading.Event()
        self._channels: dict[str, tuple[int, int]] = {}  # topic -> (server channel id, MCAP channel id)
        self._schemas: dict[str, int] = {}
        self._map_logged, self._map_dirty, self._server_map, self._last_t = -math.inf, False, False, 0.0
        self._det = _by_observer(detections)
        self._det_i: Counter[int] = Counter()
        meta = {"epoch": repr(self.epoch), "stamps": "ROS time = data stamp + epoch [s]", "frame": "map"}
        self.server = None
        self._mcap: Any = None
        self._file: Any = None
        try:
            if port is not None:
                from swarmloc.net.foxglove_ws import FoxgloveServer

                self.server = FoxgloveServer(host=host, port=port, name=name, history=history, metadata=meta)
            if mcap is not None:
                self._open_mcap(Path(mcap), meta)
            for topic in self._topics(roster):
                self._channel(topic)
        except BaseException:
            self.close()
            raise
        self.port = None if self.server is None else self.server.port

    def _open_mcap(self, path: Path, meta: dict[str, str]) -> None:
        from mcap.writer import Writer

        from swarmloc import __version__

        self._file = open(path, "wb")  # noqa: SIM115 - closed by end_recording
        self._mcap = Writer(self._file)
        self._mcap.start(profile="ros2", library=f"swarmloc {__version__}")
        self._mcap.add_metadata("swarmloc", meta)

    def _topics(self, roster: Sequence[int] | None) -> list[str]:
        """The channels advertised from the start (the truth ones only with truth, NEES only with a score too)."""
        skip = set() if self.score is not None else {"/swarmloc/nees"}
        if self.truth is None:
            skip |= {"/swarmloc/truth", "/swarmloc/nees", "truth"}  # "truth": each robot's truth channel
        names = [t for t in CHANNELS if t not in skip]
        robots = [robot_topic(r, n) for r in roster or () for n in ROBOT_CHANNELS if n not in skip]
        return names + robots

    @property
    def url(self) -> str | None:
        """The WebSocket URL to open in Foxglove or Lichtblick (None without a live server)."""
        return None if self.port is None else f"ws://127.0.0.1:{self.port}"

    @property
    def topics(self) -> list[str]:
        """Every channel advertised (or recorded) so far."""
        return list(self._channels)

    @property
    def subscriptions(self) -> int:
        """Subscriptions of the live clients now (0 without a server)."""
        return 0 if self.server is None else self.server.subscriptions

    # ------------------------------------------------------------------------------------------ channels
    def _channel(self, topic: str) -> tuple[int, int]:
        ch = self._channels.get(topic)
        if ch is None:
            kind = channel_type(topic)
            text = ros.msgdef(kind)
            ws = -1 if self.server is None else self.server.add_channel(topic, kind, text)
            rec = -1
            if self._mcap is not None:
                if kind not in self._schemas:
                    self._schemas[kind] = self._mcap.register_schema(kind, "ros2msg", text.encode())
                rec = self._mcap.register_channel(topic, "cdr", self._schemas[kind])
            ch = self._channels[topic] = (ws, rec)
        return ch

    def _publish(self, topic: str, t: float, msg: Any) -> None:
        """Publish ``msg`` on ``topic`` live and into the recording, log time ``t`` [s, ROS time]."""
        ns = ros.stamp_ns(t)
        data = ros.to_cdr(msg)
        ws, rec = self._channel(topic)
        if self._mcap is not None:
            self._mcap.add_message(rec, log_time=ns, publish_time=ns, data=data, sequence=self.counts[topic])
        if self.server is not None:
            self.server.publish(ws, ns, data)
        self.counts[topic] += 1

    # ------------------------------------------------------------------------------------------ input
    def observe(self, body: Any) -> None:
        """Show a collected :class:`Belief` or :class:`Lines` (anything else is ignored). Thread-safe; a belief
        that cannot be shown (SE(3), a stamp outside ROS time) is counted in :attr:`refused`."""
        with self._lock:
            if isinstance(body, Belief):
                try:
                    self._belief(body)
                except ValueError as exc:
                    reason = str(exc).split(",")[0][:80]
                    self.refused[reason] += 1
                    if self.refused[reason] == 1:
                        log.warning("live view: a belief of robot %s not shown: %s", body.robot, exc)
            elif isinstance(body, Lines) and self.maps.store(body) and not self._server_map:
                self._map_dirty = True
            if self._map_dirty and time.monotonic() - self._map_logged >= self.map_every:
                self._log_map()

    def _belief(self, b: Belief) -> None:
        if b.group != "SE2" or len(b.mean) != 9 or len(b.cov) != 9:
            raise ValueError(f"{b.group} beliefs are not shown (SE(2) only)")
        g, cov = np.reshape(b.mean, (3, 3)), np.reshape(b.cov, (3, 3))
        t = b.stamp + self.epoch
        stamp = ros.ros_time(t)  # ValueError outside ROS time: nothing of it is published
        xyt, C = ros.pose_covariance_world(g, cov)
        x, y, th = (float(v) for v in xyt)
        self._last_t = max(self._last_t, b.stamp)
        T, r = _types(), b.robot
        self._publish(robot_topic(r, "pose"), t, ros.pose_message(t, g, cov, frame_id="map"))
        tf = T["geometry_msgs/msg/TransformStamped"](
            header=self._header(stamp), child_frame_id=f"robot{r}",
            transform=T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
                                                       rotation=ros.quaternion(th)))  # fmt: skip
        self._publish("/tf", t, T["tf2_msgs/msg/TFMessage"](transforms=[tf]))
        ring = ellipse(np.array([x, y]), C[:2, :2])
        self._publish("/swarmloc/beliefs", t, self._markers([
            self._marker(stamp, "belief", r, _ARROW, pose=ros.pose(x, y, th), scale=(0.3, 0.06, 0.06), color=_BLUE),
            self._marker(stamp, "ellipse", r, _LINE_STRIP, scale=(0.02, 0, 0), color=_BLUE,
                         points=[*ring, ring[0]]),
            self._marker(stamp, "label", r, _TEXT, pose=ros.pose(x, y, 0.0, 0.3), scale=(0, 0, 0.2), color=_BLUE,
                         text=f"robot {r}"),
        ]))  # fmt: skip
        if b.final:
            self._final(b, g, xyt, cov, stamp)

    def _final(self, b: Belief, g: np.ndarray, xyt: np.ndarray, cov: np.ndarray, stamp: Any) -> None:
        """Truth, NEES and the detections up to a final belief's stamp."""
        t, r = b.stamp + self.epoch, b.robot
        true = None
        if self.truth is not None:
            with suppress(ValueError):  # no truth there
                true = np.asarray(self.truth(r, np.array([b.stamp])), dtype=float).reshape(3)
        if true is not None:
            T = _types()
            self._publish(robot_topic(r, "truth"), t, T["geometry_msgs/msg/PoseStamped"](
                header=self._header(stamp), pose=ros.pose(*true)))  # fmt: skip
            arrow = self._marker(stamp, "truth", r, _ARROW, pose=ros.pose(*true), scale=(0.3, 0.06, 0.06), color=_GREEN)
            self._publish("/swarmloc/truth", t, self._markers([arrow]))
            if self.score is not None:
                err = self.score(RobotTrack(times=np.array([b.stamp]), mean=xyt[None], cov=cov[None],
                                            truth=true[None]))  # fmt: skip
                vec = T["geometry_msgs/msg/Vector3"](x=float(err["nees"][0]), y=float(err["pos"][0]),
                                                     z=float(err["heading"][0]))  # fmt: skip
                self._publish("/swarmloc/nees", t, T["geometry_msgs/msg/Vector3Stamped"](
                    header=self._header(stamp, f"robot{r}"), vector=vec))  # fmt: skip
        self._detections(b, g)

    def _detections(self, b: Belief, g: np.ndarray) -> None:
        dets, i = self._det.get(b.robot, []), self._det_i[b.robot]
        arrows = []
        while i < len(dets) and dets[i].t <= b.stamp:
            d, at = dets[i], _target_at(dets[i], g)
            if at is not None:
                arrows.append(self._marker(ros.ros_time(d.t + self.epoch), f"robot{d.observer}", i % 2**31, _ARROW,
                                           scale=(0.02, 0.05, 0.08), color=_ORANGE, points=[g[:2, 2], at],
                                           lifetime=DETECTION_LIFE))  # fmt: skip
            i += 1
        self._det_i[b.robot] = i
        if arrows:
            self._publish("/swarmloc/detections", b.stamp + self.epoch, self._markers(arrows))

    # ------------------------------------------------------------------------------------------ messages
    def _header(self, stamp: Any, frame_id: str = "map") -> Any:
        return _types()["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def _markers(self, markers: list[Any]) -> Any:
        return _types()[MARKERS](markers=markers)

    def _marker(self, stamp: Any, ns: str, mid: int, kind: int, *, pose: Any = None, scale: Sequence[float] = (1, 1, 1),
                color: Sequence[float] = _GREY, points: Iterable[Any] = (), text: str = "",
                lifetime: float = 0.0, action: int = _ADD) -> Any:  # fmt: skip
        """One ``visualization_msgs/msg/Marker`` in frame ``map`` (``points`` in the plane, z = 0)."""
        T = _types()
        P, V, C = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Vector3"], T["std_msgs/msg/ColorRGBA"]
        return T["visualization_msgs/msg/Marker"](
            header=self._header(stamp), ns=ns, id=int(mid), type=kind, action=action,
            pose=ros.pose(0.0, 0.0, 0.0) if pose is None else pose,
            scale=V(x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
            color=C(r=color[0], g=color[1], b=color[2], a=color[3]),
            lifetime=T["builtin_interfaces/msg/Duration"](*ros.stamp_to_ros(lifetime)),
            frame_locked=False, points=[P(x=float(p[0]), y=float(p[1]), z=0.0) for p in points], colors=[],
            texture_resource="", texture=T["sensor_msgs/msg/CompressedImage"](
                header=self._header(stamp), format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[], text=text, mesh_resource="",
            mesh_file=T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )  # fmt: skip

    # ------------------------------------------------------------------------------------------ the map
    def show_map(self, answer: MapAnswer) -> None:
        """Show the belief server's map ``answer`` (a node's view: the team's fused map, which from then on replaces
        the map of the lines given to :meth:`observe`). Thread-safe."""
        with self._lock:
            self._server_map = True
            self._map_dirty = False
            self._log_map(answer)

    def _log_map(self, answer: MapAnswer | None = None) -> None:
        ans = self.maps.answer() if answer is None else answer
        pts = [p for fl in ans.lines for p in (fl.line[5:7], fl.line[7:9])]
        t = self._last_t + self.epoch
        marker = self._marker(ros.ros_time(t), "map", 0, _LINE_LIST, scale=(0.03, 0, 0), color=_GREY, points=pts,
                              action=_ADD if pts else _DELETE)  # fmt: skip
        self._publish("/swarmloc/map", t, self._markers([marker]))
        self._map_logged = time.monotonic()
        self._map_dirty = False

    def flush(self) -> None:
        """Log the map now if lines came since it was last logged."""
        with self._lock:
            if self._map_dirty:
                self._log_map()

    # ------------------------------------------------------------------------------------------ the end
    def end_recording(self) -> None:
        """Log the last map (:meth:`flush`) and finish the MCAP file; the live server stays up."""
        self.flush()
        with self._lock:
            if self._mcap is not None:
                self._mcap.finish()
                self._mcap = None
            if self._file is not None:
                self._file.close()
                self._file = None

    def wait(self, seconds: float = math.inf) -> bool:
        """Block for ``seconds`` (inf: until :meth:`close` or Ctrl-C); True if the view was closed meanwhile."""
        return wait_event(self._closed, seconds)  # in slices: Ctrl-C is taken whichever thread receives it

    def close(self) -> None:
        """:meth:`end_recording`, then stop the live server (its clients are disconnected)."""
        try:
            self.end_recording()
        finally:
            with self._lock:
                if self.server is not None:
                    self.server.close()
                    self.server = None
            self._closed.set()

    def __enter__(self) -> TeamView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _by_observer(events: Iterable[Any]) -> dict[int, list[Detection]]:
    """The detections among ``events``, per observer, in time order."""
    out: dict[int, list[Detection]] = {}
    for e in events:
        if isinstance(e, Detection):
            out.setdefault(e.observer, []).append(e)
    for v in out.values():
        v.sort(key=lambda d: d.t)
    return out
