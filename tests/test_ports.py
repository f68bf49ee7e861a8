"""Free ports for local teams: the OS's pick, or a range of their own (SWARMLOC_PORT_RANGE), which each pytest-xdist
worker gets so that two teams starting at once in two workers never take each other's ports."""

from __future__ import annotations

import os
import socket

import pytest
from conftest import worker_port_range

from swarmloc.net.transport import PORT_RANGE_ENV, free_ports, port_range

pytestmark = pytest.mark.unit


def test_ports_come_from_the_range_distinct_and_skip_one_taken(monkeypatch):
    monkeypatch.setenv(PORT_RANGE_ENV, "10000-10499")
    with socket.socket() as s:  # a port of the range in use: never handed out
        s.bind(("127.0.0.1", 10123))
        s.listen()
        for _ in range(20):
            ports = free_ports(25)
            assert len(set(ports)) == 25 and all(10000 <= p <= 10499 for p in ports) and 10123 not in ports
    monkeypatch.setenv(PORT_RANGE_ENV, "10000-10001")
    with pytest.raises(ValueError, match="3 ports asked, SWARMLOC_PORT_RANGE holds 2"):
        free_ports(3)


def test_two_calls_never_hand_out_the_same_port_until_the_range_is_used_up(monkeypatch):
    """A port handed out but not yet bound looks free: a second call (a team's hub, then its members) must not
    return it again while the range holds others; once every port was handed out, they are handed out again."""
    from swarmloc.net import transport

    monkeypatch.setattr(transport, "_HANDED", set())
    monkeypatch.setenv(PORT_RANGE_ENV, "10000-10009")
    first, second = free_ports(4), free_ports(4)
    assert len(set(first) | set(second)) == 8
    third = free_ports(4)  # 2 left unhanded: the memory starts again, still 4 distinct ports of the range
    assert len(set(third)) == 4 and all(10000 <= p <= 10009 for p in third)
    monkeypatch.delenv(PORT_RANGE_ENV)
    a, b = free_ports(3), free_ports(3)  # the OS's picks: never the same twice either
    assert not set(a) & set(b)


@pytest.mark.parametrize("bad", ["10000", "9-20", "20000-10000", "a-b", "10000-70000"])
def test_a_malformed_range_is_refused_naming_the_variable(bad, monkeypatch):
    monkeypatch.setenv(PORT_RANGE_ENV, bad)
    with pytest.raises(ValueError, match="SWARMLOC_PORT_RANGE must be LO-HI"):
        free_ports(1)


def test_without_a_range_the_os_picks(monkeypatch):
    monkeypatch.delenv(PORT_RANGE_ENV, raising=False)
    assert port_range() is None and len(set(free_ports(3))) == 3


def test_each_xdist_worker_has_a_range_of_its_own_below_the_ephemeral_ports():
    ranges = [tuple(map(int, worker_port_range(f"gw{k}").split("-"))) for k in range(45)]
    assert ranges[0] == (10000, 10499) and ranges[1] == (10500, 10999)
    assert all(a[1] < b[0] for a, b in zip(ranges, ranges[1:], strict=False)) and ranges[-1][1] < 32768
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker:  # this run is under xdist: its worker's range is set for every test and process it starts
        assert os.environ[PORT_RANGE_ENV] == worker_port_range(worker)
