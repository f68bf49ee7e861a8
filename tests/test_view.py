"""The live view (Foxglove SDK): a real WebSocket client of Foxglove's protocol (subprotocol ``foxglove.sdk.v1``)
subscribes to the running view server while a short simulated team runs and checks the beliefs and map lines it
receives; the MCAP recording of the same run opens with the ``mcap`` library's reader."""

from __future__ import annotations

import asyncio
import json
import struct
import threading
import time

import numpy as np
import pytest
import websockets
from mcap.reader import make_reader

from swarmloc.experiments.sources import load_source
from swarmloc.lie import SE2
from swarmloc.net.server import MapStore
from swarmloc.net.team import launch_team
from swarmloc.net.view import TOPICS, TeamView

pytestmark = pytest.mark.network


class Client(threading.Thread):
    """A Foxglove WebSocket client: subscribes to every advertised channel, keeps what arrives per topic."""

    def __init__(self, url: str) -> None:
        super().__init__(daemon=True)
        self.url, self.got, self.topics = url, {}, {}
        self.subscribed, self.stop_ = threading.Event(), threading.Event()
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            asyncio.run(self._main())
        except websockets.ConnectionClosedOK:
            pass  # the view server stopped
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            self.error = exc

    async def _main(self) -> None:
        async with websockets.connect(self.url, subprotocols=["foxglove.sdk.v1"]) as ws:
            while not self.stop_.is_set():
                try:
                    m = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                if isinstance(m, str):
                    msg = json.loads(m)
                    if msg["op"] == "advertise":
                        subs = []
                        for i, ch in enumerate(msg["channels"]):
                            self.topics[100 + i] = ch["topic"]
                            subs.append({"id": 100 + i, "channelId": ch["id"]})
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    continue
                op, sub, log_time = struct.unpack_from("<BIQ", m)
                if op == 1:
                    self.got.setdefault(self.topics[sub], []).append((log_time, m[13:]))


def test_live_view_streams_beliefs_and_map_and_records_mcap(tmp_path):
    src = load_source("sim:corridor", robots=2, duration=6.0, seed=1)
    view = TeamView(port=0, mcap=tmp_path / "team.mcap", truth=src.truth, detections=src.events, roster=src.robots)
    client = Client(view.url)
    client.start()
    try:
        end = time.monotonic() + 10
        while view.subscriptions < len(TOPICS) and time.monotonic() < end:
            client.join(0.05)
        assert view.subscriptions == len(TOPICS), client.error
        run = launch_team(src=src, robots=2, duration=6.0, seed=1, server=True, max_wall=150.0, view=view)
        view.flush()  # the last map
        end = time.monotonic() + 10
        while sum(len(v) for v in client.got.values()) < sum(view.counts.values()) and time.monotonic() < end:
            client.join(0.05)
    finally:
        view.close()
        client.stop_.set()
        client.join(10)
    assert not client.is_alive() and client.error is None
    assert not run.counts["timed_out"] and run.beliefs and run.lines
    got = {t: [json.loads(p) for _, p in v] for t, v in client.got.items() if t != "/swarmloc/scene"}
    # every message logged arrived, per topic
    assert {t: len(v) for t, v in client.got.items()} == dict(view.counts)
    # the beliefs: the final ones are the collected run's, with their values
    finals = {(b["robot"], b["stamp"]): b for b in got["/swarmloc/beliefs"] if b["final"]}
    assert {r for r, _ in finals} == {0, 1}
    for k, b in run.beliefs.items():
        if b.final:
            x, y, th = SE2.to_xytheta(np.reshape(b.mean, (3, 3)))
            v = finals[k]
            np.testing.assert_allclose([v["x"], v["y"], v["theta"]], [x, y, th], atol=1e-12)
            assert v["cov"] == list(b.cov) and len(v["ellipse"]) == 24
    # ground truth where known, and the detections
    tr = got["/swarmloc/truth"][-1]
    np.testing.assert_allclose([tr["x"], tr["y"], tr["theta"]], src.truth(tr["robot"], np.array([tr["stamp"]]))[0])
    assert got["/swarmloc/detections"] and all(d["at"] is not None for d in got["/swarmloc/detections"])
    # the map: the last one is the fusion of every robot's lines, and the belief server's map
    ms = MapStore(src.robots)
    for m in run.lines:
        ms.store(m)
    want = ms.answer()
    last = got["/swarmloc/map"][-1]
    assert last["messages"] == len(run.lines) == want.messages and len(last["lines"]) == len(want.lines) >= 2
    for a, b in zip(last["lines"], want.lines, strict=True):
        assert [a["rho"], a["alpha"], *a["cov"], *a["ends"]] == list(b.line) and a["robots"] == list(b.robots)
    assert run.map is not None and [fl.line for fl in run.map.lines] == [fl.line for fl in want.lines]
    # the recording: every message, readable by the mcap library
    with open(tmp_path / "team.mcap", "rb") as f:
        reader = make_reader(f)
        recorded = {}
        for _schema, channel, message in reader.iter_messages():
            recorded.setdefault(channel.topic, []).append(message.data)
        assert {t: len(v) for t, v in recorded.items()} == dict(view.counts)
        assert recorded["/swarmloc/scene"] and any(
            s.name == "foxglove.SceneUpdate" for s in reader.get_summary().schemas.values()
        )
    assert json.loads(recorded["/swarmloc/map"][-1]) == last
    # the same beliefs (the recording is in log-time order, the stream in arrival order)
    assert sorted(recorded["/swarmloc/beliefs"]) == sorted(p for _, p in client.got["/swarmloc/beliefs"])


def test_node_view_streams_its_belief_detections_truth_and_the_servers_map(tmp_path):
    """``swarmloc node --view``: robot 1's node (a thread here, as in a node process) serves its own beliefs with
    their ellipses, its detections, ground truth and the belief server's fused map, which it asks the server for;
    robot 0 and the server run beside it, each on its own Zenoh session on 127.0.0.1."""
    from swarmloc.net.entry import node_main
    from swarmloc.net.server import ServerProcess
    from swarmloc.net.transport import free_ports, open_session

    src = load_source("sim:corridor", robots=2, duration=6.0, seed=2)
    eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(3)]
    sessions = [open_session([eps[2]], eps[:2])]  # the server's; each node opens its own
    server = ServerProcess(sessions[0], "nview", src.robots)
    dets = [e for e in src.own_events(1) if getattr(e, "observer", None) == 1]  # (robot 0 sees no one here)
    assert dets
    view = TeamView(port=0, mcap=tmp_path / "node.mcap", truth=src.truth, detections=dets, roster=src.robots,
                    name="swarmloc node 1")  # fmt: skip
    client = Client(view.url)
    client.start()
    threads = [threading.Thread(target=server.run, kwargs={"max_wall": 120}, daemon=True)]
    reports = {}

    def node(r, v):
        reports[r] = node_main(src=src, robot=r, team="nview", estimator="expfusion", listen=[eps[r]],
                               connect=[x for x in eps if x != eps[r]], max_wall=100.0, view=v)  # fmt: skip

    try:
        end = time.monotonic() + 10
        while view.subscriptions < len(TOPICS) and time.monotonic() < end:
            client.join(0.05)
        assert view.subscriptions == len(TOPICS), client.error
        threads[0].start()
        threads += [threading.Thread(target=node, args=(r, v), daemon=True) for r, v in ((0, None), (1, view))]
        for th in threads[1:]:
            th.start()
        for th in threads[1:]:
            th.join(120)
        assert not any(th.is_alive() for th in threads[1:]) and set(reports) == {0, 1}
        end = time.monotonic() + 10
        while sum(len(v) for v in client.got.values()) < sum(view.counts.values()) and time.monotonic() < end:
            client.join(0.05)
        final_map = server.maps.answer()
    finally:
        server.stop()
        threads[0].join(10)
        view.close()
        client.stop_.set()
        client.join(10)
        for s in sessions:
            s.close()
    assert not client.is_alive() and client.error is None and not threads[0].is_alive()
    assert {t: len(v) for t, v in client.got.items()} == dict(view.counts)
    got = {t: [json.loads(p) for _, p in v] for t, v in client.got.items() if t != "/swarmloc/scene"}
    # only robot 1's beliefs, each with its 95% ellipse; its truth; its own detections
    beliefs = got["/swarmloc/beliefs"]
    assert beliefs and {b["robot"] for b in beliefs} == {1} and all(len(b["ellipse"]) == 24 for b in beliefs)
    assert any(b["final"] for b in beliefs)
    tr = got["/swarmloc/truth"][-1]
    np.testing.assert_allclose([tr["x"], tr["y"], tr["theta"]], src.truth(1, np.array([tr["stamp"]]))[0])
    assert got["/swarmloc/detections"] and {d["observer"] for d in got["/swarmloc/detections"]} == {1}
    # the map shown is the server's (lines of both robots), and the last one its map at the node's end
    maps = got["/swarmloc/map"]
    assert maps and any({0, 1} <= set(r for ln in m["lines"] for r in ln["robots"]) for m in maps)
    last = maps[-1]
    assert 0 < last["messages"] <= final_map.messages
    if last["messages"] == final_map.messages:
        assert [[*a["cov"], *a["ends"]] for a in last["lines"]] == [list(b.line[2:9]) for b in final_map.lines]
    with open(tmp_path / "node.mcap", "rb") as f:
        recorded = {}
        for _schema, channel, message in make_reader(f).iter_messages():
            recorded.setdefault(channel.topic, []).append(message.data)
    assert {t: len(v) for t, v in recorded.items()} == dict(view.counts)
