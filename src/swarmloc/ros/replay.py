"""The ROS node's outputs computed offline from recorded input messages: the same conversions
(:class:`~swarmloc.ros.timeline.InputTimeline`), the same nodes and record times, run by the in-process driver
(:func:`swarmloc.runner.run`) instead of over the network. What a team of :class:`~swarmloc.ros.node.RosNode`\\ s
publishes live equals what this gives on the messages they received (the live node's settled outputs are the
in-process run's final beliefs), so a recording can be localized again at full speed, like robot_localization on
a played bag.

:func:`replay_messages` takes each robot's messages in arrival order; :func:`replay_bag` reads a rosbag2
(``.db3`` or ``.mcap``, with rosbags' reader) whose topics the nodes' parameters name, and writes the outputs to a
new bag.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarmloc.events import Detection, Event, Odometry
from swarmloc.gaussian import GroupGaussian
from swarmloc.lie import SE2
from swarmloc.ros import convert as cv
from swarmloc.ros.args import RosArgs
from swarmloc.ros.node import TOPIC_PARAMS, initial_belief, outputs, timeline_of
from swarmloc.ros.params import RosParams
from swarmloc.ros.timeline import InputTimeline, record_times, refused_key, refused_record

KINDS = ("odometry", "detections", "initialpose")


@dataclass
class ReplayResult:
    """Per robot: its output times ``(T,)`` [s], beliefs (:class:`~swarmloc.gaussian.GroupGaussian`), the input
    timeline (counts, refusals, odometry samples); the run's counters."""

    times: dict[int, np.ndarray] = field(default_factory=dict)
    beliefs: dict[int, list[GroupGaussian]] = field(default_factory=dict)
    timelines: dict[int, InputTimeline] = field(default_factory=dict)
    stats: dict[str, int] = field(default_factory=dict)

    def outputs(self, robot: int, params: RosParams) -> list[tuple[float, Any, Any | None]]:
        """``(t, nav_msgs/Odometry, tf2_msgs/TFMessage or None)`` per output time, as the live node publishes."""
        tl = self.timelines[robot]
        times = self.times[robot].tolist()
        return [(t, *outputs(params, t, b, *tl.odom_at(t))) for t, b in zip(times, self.beliefs[robot], strict=True)]


def replay_messages(
    messages: Mapping[int, Sequence[tuple[str, Any]]],
    params: Mapping[int, RosParams],
    upto: float | None = None,
    refused: Iterable[Mapping[str, Any]] = (),
) -> ReplayResult:
    """Localize offline: ``messages[robot]`` its ``(kind, message)`` in arrival order (``kind`` one of
    :data:`KINDS`), ``params[robot]`` its node's parameters (the same estimator and team for all). Outputs at the
    node's times ``t0 + k / frequency`` up to its latest input (or ``upto``). ``refused``: input events a live node
    refused (:meth:`~swarmloc.ros.node.RosNode.refused_inputs`, records of
    :func:`~swarmloc.ros.timeline.refused_record`), left out of the events the messages make (a late odometry
    message's sample is kept, its interval left out): the replay of what the nodes read. One the messages do not make
    is a ValueError."""
    from swarmloc.net.entry import make_node
    from swarmloc.runner import run

    res, nodes, events = ReplayResult(), [], []
    left_out = Counter(refused_key(x) for x in refused)
    ends: dict[int, float] = {}
    for r, msgs in sorted(messages.items()):
        p = params[r]
        tl = timeline_of(p, r)
        evs: list[Event] = []
        for kind, m in msgs:
            if kind not in KINDS:
                raise ValueError(f"replay_messages: kind {kind!r} is not one of {KINDS}")
            evs += getattr(tl, kind)(m)
        evs = leave_out(evs, left_out)
        res.timelines[r] = tl
        if tl.t0 is None:
            continue
        node = make_node(p.estimator, r, initial_belief(p, tl.initial), p.config(), p.landmark_table(), team=p.team_ids)
        node.start(tl.t0)
        nodes.append(node)
        events += evs
        ends[r] = max([tl.t0, *(float(e.t) for e in evs)]) if upto is None else upto
    if +left_out:
        raise ValueError(f"replay_messages: refused inputs the messages do not make: {sorted(+left_out)}")
    if not nodes:
        return res
    events.sort(key=lambda e: (float(e.stamp), 1 if hasattr(e, "observer") else 2))
    rts = {r: record_times(res.timelines[r].t0, params[r].frequency, ends[r]) for r in ends}  # type: ignore[arg-type]
    run_result = run(nodes, events, record_times=np.unique(np.concatenate(list(rts.values()))))
    res.stats = dict(run_result.stats)
    for r, rt in rts.items():
        tr = run_result.tracks[r]
        keep = np.isin(tr.times, rt)
        res.times[r] = tr.times[keep]
        res.beliefs[r] = [GroupGaussian(SE2, SE2.from_xytheta(x), c, validate=False)
                          for x, c in zip(tr.mean[keep], tr.cov[keep], strict=True)]  # fmt: skip
    return res


def leave_out(events: list[Event], keys: Counter[tuple[Any, ...]]) -> list[Event]:
    """``events`` less those named in ``keys`` (:func:`~swarmloc.ros.timeline.refused_key`), each as many times as
    counted there; ``keys`` is decremented for each event left out."""
    out = []
    for e in events:
        k = refused_key(refused_record(e, "")) if isinstance(e, Odometry | Detection) else None
        if k is not None and keys[k] > 0:
            keys[k] -= 1
        else:
            out.append(e)
    return out


def node_sections(params_file: str) -> list[tuple[str, str]]:
    """``(namespace, node name)`` of every section of a params file keyed by a fully qualified node name
    (``/robot1/swarmloc``): the nodes a recording is replayed for."""
    import yaml

    data = yaml.safe_load(Path(params_file).read_text(encoding="utf-8")) or {}
    out = []
    for key in data:
        k = str(key)
        if k.startswith("/") and "*" not in k and k.count("/") >= 2:
            ns, _, name = k.rpartition("/")
            out.append((ns, name))
    return out


def replay_bag(bag: str, params_file: str, out: str | None = None, args: RosArgs | None = None) -> ReplayResult:
    """Replay a rosbag2 for every node of ``params_file`` (its ``/<ns>/<name>`` sections; their topics resolved and
    remapped as live); with ``out``, write the outputs (``Odometry``, ``/tf``) to a new rosbag2 there."""
    from rosbags.highlevel import AnyReader

    from swarmloc.rmw import typestore
    from swarmloc.ros.params import load_params

    args = args or RosArgs()
    params: dict[int, RosParams] = {}
    route: dict[str, tuple[int, str]] = {}
    for ns, name in node_sections(params_file):
        p = load_params([params_file, *args.params_files], args.params, name, ns)
        params[p.robot_id] = p
        for kind, key in zip(KINDS, TOPIC_PARAMS[:3], strict=True):
            route[args.resolve(getattr(p, key), ns, name)] = (p.robot_id, kind)
    if not params:
        raise ValueError(f"{params_file}: no section keyed by a node's full name (/<namespace>/<node>)")
    messages: dict[int, list[tuple[str, Any]]] = {r: [] for r in params}
    with AnyReader([Path(bag)], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if c.topic in route]
        for conn, _t, raw in reader.messages(connections=conns):
            r, kind = route[conn.topic]
            messages[r].append((kind, reader.deserialize(raw, conn.msgtype)))
    res = replay_messages(messages, params)
    if out is not None:
        _write_outputs(res, params, out)
    return res


def _write_outputs(res: ReplayResult, params: Mapping[int, RosParams], out: str) -> None:
    from rosbags.rosbag2 import Writer

    from swarmloc.rmw import typestore

    ts = typestore()
    with Writer(Path(out), version=Writer.VERSION_LATEST) as w:
        tf = w.add_connection("/tf", cv.TF, typestore=ts)
        for r in sorted(res.times):
            c = w.add_connection(f"/robot{r}/odometry/filtered", cv.ODOMETRY, typestore=ts)
            for t, odo, tfm in res.outputs(r, params[r]):
                ns = int(round(t * 1e9))
                w.write(c, ns, ts.serialize_cdr(odo, cv.ODOMETRY))
                if tfm is not None:
                    w.write(tf, ns, ts.serialize_cdr(tfm, cv.TF))
