"""Live inputs over Zenoh in swarmloc's own schema (robots without ROS): three ``swarmloc node --source
zenoh:sim:random`` processes (Zenoh peers on 127.0.0.1) localize from the odometry and detections this script
publishes on ``swarmloc/<team>/input/<robot>/{odom,det,progress}`` as they happen (2x real time, 4 s of data);
it prints the beliefs the nodes publish. The team has keys (made in a temporary folder): each robot's inputs are
signed with its key, and its node takes only those (anybody else's are refused and counted in its report).

    PYTHONPATH=src python examples/live_zenoh.py
"""

import subprocess
import sys
import time

import numpy as np

from swarmloc.events import Detection, Odometry
from swarmloc.experiments.sources import load_source
from swarmloc.lie import SE2
from swarmloc.live.zenoh_input import InputPublisher
from swarmloc.net.auth import Auth, TeamKeys, open_envelope
from swarmloc.net.schema import Belief
from swarmloc.net.transport import free_ports, open_session, robot_key

SPEED, TEAM = 2.0, "zexample"
src = load_source("sim:random", robots=3, duration=4.0, seed=1)
eps = [f"tcp/127.0.0.1:{p}" for p in free_ports(4)]
keys = TeamKeys(src.robots)  # robot<id>.key, server.key, collector.key and roster.json in a temporary folder
nodes = [
    subprocess.Popen(
        [
            sys.executable,
            "-m",
            "swarmloc.cli",
            "node",
            "--robot",
            str(r),
            "--team",
            TEAM,
            *keys.args(r),
            "--source",
            "zenoh:sim:random",
            "--robots",
            "3",
            "--duration",
            "4",
            "--seed",
            "1",
            "--estimator",
            "rdl",
            "--max-wall",
            "60",
            "--listen",
            eps[i],
            "--connect",
            ",".join(e for e in eps[:3] if e != eps[i]),
        ],
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    for i, r in enumerate(src.robots)
]
session = open_session([eps[3]], eps[:3])


def show(sample) -> None:
    b = open_envelope(reader, str(sample.key_expr), sample.payload.to_bytes(), TEAM, src.robots, server_ok=False,
                      publication=True).body  # fmt: skip
    if isinstance(b, Belief) and b.final:
        x, y, th = SE2.to_xytheta(np.reshape(b.mean, (3, 3)))
        err = np.hypot(*(np.array([x, y]) - src.truth(b.robot, np.array([b.stamp]))[0, :2]))
        print(f"robot {b.robot} at {b.stamp:4.2f} s: x={x:6.3f} y={y:6.3f} theta={th:6.3f}  (error {err:.3f} m)")


reader = Auth(keys.roster)  # verifies the nodes' signed beliefs
sub = session.declare_subscriber(robot_key(TEAM, "*", "belief"), handler=show)
pubs = {r: InputPublisher(session, TEAM, r, auth=keys.auth(r)) for r in src.robots}  # each robot's driver, its key
for p in pubs.values():  # the node processes start (imports, Zenoh): what is sent before they subscribe is lost
    p.wait_matched(timeout=30)
known = sorted((e.t, i, e) for i, e in enumerate(src.events) if isinstance(e, Odometry | Detection))
w0 = time.monotonic()
for t, _, e in known:
    time.sleep(max(0.0, w0 + (t - src.t_start) / SPEED - time.monotonic()))
    pubs[e.robot if isinstance(e, Odometry) else e.observer].push(e)
for p in pubs.values():
    p.end()
codes = [n.wait(timeout=60) for n in nodes]
print("node exit codes:", codes)
sub.undeclare()
session.close()
keys.close()
