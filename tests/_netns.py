"""A second host for tests: a Linux network namespace joined to this one by a veth pair (needs root and ``ip netns``).

    with stranger_host() as ns:               # ns.here: this side's address, ns.there: the stranger's
        team = open_session([f"tcp/{ns.here}:{port}"])
        out = ns.run([sys.executable, "attacker.py", "--connect", f"tcp/{ns.here}:{port}"], timeout=60)

A process run in the namespace (:meth:`NetNs.run`, :meth:`NetNs.popen`) has its own interfaces: its own loopback
(``127.0.0.1`` there is not this host's) and the veth end ``there``, with a default route through ``here``: it
reaches every address of this host (a stranger on the network routes to the host's other interfaces too), never
this host's loopback; it shares the file system, so it can run this repository's Python. Names are unique per
process and call (a namespace ``stranger-<pid>-<n>``, veths ``sv<n><pid>a``/``b``), the /30 subnet is the first of
``10.231.<k>.0/30`` not already on an interface (so parallel runs do not collide), and everything is torn down on
exit, processes started with :meth:`NetNs.popen` killed first.
"""

from __future__ import annotations

import ipaddress
import itertools
import os
import subprocess
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

_count = itertools.count()


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=30)


def _free_subnet() -> ipaddress.IPv4Network:
    used = subprocess.run(["ip", "-o", "-4", "addr", "show"], check=True, capture_output=True, text=True).stdout
    for k in range(256):
        for j in range(0, 256, 4):
            net = ipaddress.IPv4Network(f"10.231.{k}.{j}/30")
            if f" {net[1]}/" not in used and f" {net[2]}/" not in used:
                return net
    raise RuntimeError("no free /30 subnet in 10.231.0.0/16")


@dataclass
class NetNs:
    """A network namespace ``name`` whose veth end has address ``there``; this host's end has ``here``."""

    name: str
    here: str
    there: str
    procs: list[subprocess.Popen] = field(default_factory=list)

    def command(self, cmd: Sequence[str]) -> list[str]:
        """``cmd`` as run inside the namespace."""
        return ["ip", "netns", "exec", self.name, *cmd]

    def run(self, cmd: Sequence[str], **kw: Any) -> subprocess.CompletedProcess:
        """``subprocess.run(cmd, **kw)`` inside the namespace (``capture_output`` and ``text`` unless given)."""
        kw.setdefault("capture_output", True)
        kw.setdefault("text", True)
        return subprocess.run(self.command(cmd), **kw)

    def popen(self, cmd: Sequence[str], **kw: Any) -> subprocess.Popen:
        """``subprocess.Popen(cmd, **kw)`` inside the namespace; killed on exit if still running."""
        p = subprocess.Popen(self.command(cmd), **kw)
        self.procs.append(p)
        return p


@contextmanager
def stranger_host(prefix: str = "stranger") -> Iterator[NetNs]:
    """A namespace ``<prefix>-<pid>-<n>`` joined to this one by a veth pair (module docstring); torn down on exit."""
    n = next(_count)
    ns = NetNs(f"{prefix}-{os.getpid()}-{n}", "", "")
    a, b = f"sv{n}{os.getpid()}a"[:15], f"sv{n}{os.getpid()}b"[:15]
    made: list[list[str]] = []
    try:
        _ip("netns", "add", ns.name)
        made.append(["netns", "del", ns.name])
        _ip("link", "add", a, "type", "veth", "peer", "name", b)
        made.append(["link", "del", a])  # deleting one end deletes the pair
        net = _free_subnet()
        ns.here, ns.there = str(net[1]), str(net[2])
        _ip("link", "set", b, "netns", ns.name)
        _ip("addr", "add", f"{ns.here}/30", "dev", a)
        _ip("link", "set", a, "up")
        _ip("-n", ns.name, "addr", "add", f"{ns.there}/30", "dev", b)
        _ip("-n", ns.name, "link", "set", b, "up")
        _ip("-n", ns.name, "link", "set", "lo", "up")
        _ip("-n", ns.name, "route", "add", "default", "via", ns.here)  # every address of this host, not only here
        yield ns
    finally:
        for p in ns.procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        for args in reversed(made):
            try:
                _ip(*args)
            except subprocess.CalledProcessError:
                pass  # the veth went with the namespace
