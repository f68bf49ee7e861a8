"""Zenoh over TLS on loopback: server authentication, mutual TLS, rejected certificates, access control.

Everything runs on 127.0.0.1 with ports from :func:`free_ports`; certificates are made in a temporary directory
with the ``openssl`` command line (a test needs it and fails saying so where it is absent). Every wait is
bounded (a negative check waits 2 s for something that must not arrive) and sessions are closed in ``finally``.

Findings with eclipse-zenoh 1.10.2 (see ``docs/network.md``):

- TLS keys: ``transport/link/tls/root_ca_certificate``, ``listen_private_key``, ``listen_certificate``,
  ``enable_mtls``, ``connect_private_key``, ``connect_certificate``. All work in the Python package.
- The listener's certificate must carry a subjectAltName for the dialled address (IP:127.0.0.1 here); one with the
  address only in its common name is rejected.
- A failed handshake does not fail ``zenoh.open``: the session opens, retries the endpoint, and delivers nothing.
- ``access_control`` (rules, subjects, policies) works between two peers; subjects by ``cert_common_names`` and
  by ``interfaces`` (``lo``) both match. A common-name subject matches the connecting peer only with
  ``enable_mtls`` on the listening side (without it the listener does not learn the name). A ``deny`` rule beats
  an ``allow`` only within one subject's policies: a link matching several subjects gets a message through as soon
  as one of them allows it. Both limits are demonstrated in ``test_acl_deny_inbox``.
- A session given no listen endpoint still listens, on Zenoh's default ``tcp/[::]:0`` (every interface); the tests
  pass ``listen/endpoints: []`` for such sessions and check that every endpoint is on 127.0.0.1.
- ``test_doc_config`` loads the JSON5 configuration printed in ``docs/network.md`` and checks what it allows.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from swarmloc.net.transport import free_ports, zenoh_config

pytestmark = pytest.mark.network


OPENSSL = shutil.which("openssl")

DOC = Path(__file__).resolve().parents[1] / "docs" / "network.md"
TLS = "transport/link/tls/"
TEAM = "alpha"
NEGATIVE_WAIT = 2.0
CONNECT_WAIT = 5.0


def _openssl(*args: str, cwd: Path) -> None:
    if OPENSSL is None:
        pytest.fail("these tests make their certificates with the openssl command line: install openssl")
    subprocess.run([OPENSSL, *args], cwd=cwd, check=True, capture_output=True, timeout=30)


def _make_ca(d: Path, name: str) -> None:
    _openssl(
        "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes", "-days", "2",
        "-keyout", f"{name}.key", "-out", f"{name}.pem", "-subj", f"/CN=swarmloc-{name}",
        "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign",
        cwd=d,
    )  # fmt: skip


def _make_cert(d: Path, name: str, cn: str, ca: str = "ca", san: bool = True) -> None:
    """``<name>.key``/``<name>.pem`` with common name ``cn`` signed by ``<ca>``, as in docs/network.md."""
    _openssl(
        "req", "-new", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
        "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={cn}",
        cwd=d,
    )  # fmt: skip
    ext = "basicConstraints=critical,CA:FALSE\nextendedKeyUsage=serverAuth,clientAuth\n"
    (d / f"{name}.ext").write_text(("subjectAltName=IP:127.0.0.1,DNS:localhost\n" if san else "") + ext)
    _openssl(
        "x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key", "-CAcreateserial",
        "-days", "2", "-extfile", f"{name}.ext", "-out", f"{name}.pem",
        cwd=d,
    )  # fmt: skip


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The team's CA with certificates ``robot-1``, ``robot-2``, ``server``, ``intruder``; another CA ``other-ca``
    with a ``robot-2`` of its own (``forged``); ``nosan``: the team's CA, 127.0.0.1 only as common name."""
    d = tmp_path_factory.mktemp("pki")
    _make_ca(d, "ca")
    _make_ca(d, "other-ca")
    for name in ("robot-1", "robot-2", "server", "intruder"):
        _make_cert(d, name, name)
    _make_cert(d, "forged", "robot-2", ca="other-ca")
    _make_cert(d, "nosan", "127.0.0.1", san=False)
    return d


def _tls(pki: Path, cert: str | None, *, mtls: bool) -> dict[str, Any]:
    """TLS settings of a peer that trusts the team's CA and both listens and connects with ``cert`` (None: no
    certificate of its own)."""
    extra: dict[str, Any] = {TLS + "root_ca_certificate": str(pki / "ca.pem"), TLS + "enable_mtls": mtls}
    if cert is not None:
        key, pem = str(pki / f"{cert}.key"), str(pki / f"{cert}.pem")
        extra.update({TLS + "listen_private_key": key, TLS + "listen_certificate": pem})
        extra.update({TLS + "connect_private_key": key, TLS + "connect_certificate": pem})
    return extra


@contextlib.contextmanager
def _sessions() -> Iterator[Callable[..., Any]]:
    """``open(listen, connect, config_file=None, extra=None)`` opens a session; all are closed on exit."""
    opened: list[Any] = []

    def open_(listen=(), connect=(), config_file=None, extra=None) -> Any:
        # no listen endpoint: none at all (Zenoh's default for a peer is tcp/[::]:0, every interface)
        extra = {**({} if listen else {"listen/endpoints": []}), **(extra or {})}
        cfg = zenoh_config(listen, connect, config_file, extra)
        for what in ("listen", "connect"):  # loopback only, whatever a configuration file says
            endpoints = json.loads(cfg.get_json(f"{what}/endpoints"))
            assert isinstance(endpoints, list) and all(e.startswith("tls/127.0.0.1:") for e in endpoints), endpoints
        s = zenoh.open(cfg)
        opened.append(s)
        return s

    try:
        yield open_
    finally:
        for s in reversed(opened):
            s.close()


def _until(cond: Callable[[], bool], timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return cond()


def _collect(session: Any, key_expr: str) -> tuple[Any, set[tuple[str, str]]]:
    """A subscriber on ``key_expr`` filling a set of ``(key, payload)``."""
    got: set[tuple[str, str]] = set()
    sub = session.declare_subscriber(key_expr, lambda s: got.add((str(s.key_expr), s.payload.to_string())))
    return sub, got


def _answers(session: Any, selector: str, timeout: float = 1.0) -> list[str]:
    """Payloads of the ok replies to a get."""
    return sorted(r.ok.payload.to_string() for r in session.get(selector, timeout=timeout) if r.ok is not None)


def _serve(session: Any, key: str, answer: str) -> Any:
    return session.declare_queryable(key, lambda q: q.reply(q.key_expr, answer))


def _put_until(session: Any, key: str, value: str, got: set[tuple[str, str]], timeout: float = CONNECT_WAIT) -> bool:
    """Put ``value`` on ``key`` every 0.1 s until ``got`` holds something (the link is up and routed) or timeout."""
    end = time.monotonic() + timeout
    while not got and time.monotonic() < end:
        session.put(key, value)
        time.sleep(0.1)
    return bool(got)


def _put_for(puts: list[tuple[Any, str, str]], seconds: float) -> None:
    """Repeat each ``(session, key, value)`` put every 0.1 s for ``seconds``."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for session, key, value in puts:
            session.put(key, value)
        time.sleep(0.1)


def _belief(robot: int | str) -> str:
    return f"swarmloc/{TEAM}/robot/{robot}/belief"


def _inbox(robot: int | str) -> str:
    return f"swarmloc/{TEAM}/robot/{robot}/inbox"


def test_tls_server_auth(pki: Path) -> None:
    """One-way TLS: the listener presents robot-1's certificate, the connecting peer only trusts the CA."""
    (p1,) = free_ports(1)
    with _sessions() as open_:
        a = open_(listen=[f"tls/127.0.0.1:{p1}"], extra=_tls(pki, "robot-1", mtls=False))
        b = open_(connect=[f"tls/127.0.0.1:{p1}"], extra=_tls(pki, None, mtls=False))
        _, got = _collect(a, _belief("*"))
        assert _put_until(b, _belief(2), "hello", got)
        assert got == {(_belief(2), "hello")}
        assert list(b.info.peers_zid()) == [a.info.zid()]


def test_mtls_put_and_get(pki: Path) -> None:
    """Mutual TLS: both peers present certificates of the team's CA; puts and gets work both ways."""
    p1, p2 = free_ports(2)
    with _sessions() as open_:
        a = open_(listen=[f"tls/127.0.0.1:{p1}"], extra=_tls(pki, "robot-1", mtls=True))
        b = open_(
            listen=[f"tls/127.0.0.1:{p2}"], connect=[f"tls/127.0.0.1:{p1}"], extra=_tls(pki, "robot-2", mtls=True)
        )
        _, got_a = _collect(a, _inbox(1))
        _, got_b = _collect(b, _inbox(2))
        _serve(a, f"swarmloc/{TEAM}/robot/1/query", "from-1")
        _serve(b, f"swarmloc/{TEAM}/robot/2/query", "from-2")
        end = time.monotonic() + CONNECT_WAIT
        while not (got_a and got_b) and time.monotonic() < end:
            b.put(_inbox(1), "to-1")
            a.put(_inbox(2), "to-2")
            time.sleep(0.1)
        assert got_a == {(_inbox(1), "to-1")} and got_b == {(_inbox(2), "to-2")}
        assert _answers(a, f"swarmloc/{TEAM}/robot/2/query") == ["from-2"]
        assert _answers(b, f"swarmloc/{TEAM}/robot/1/query") == ["from-1"]


REJECTS = {
    # case: (listener's certificate, connector's certificate, mTLS); both sides trust the team's CA only
    "client cert from other CA": ("robot-1", "forged", True),
    "no client cert under mTLS": ("robot-1", None, True),
    "server cert from other CA": ("forged", None, False),
    "server cert without SAN": ("nosan", None, False),
}


@pytest.mark.parametrize("case", list(REJECTS))
def test_tls_rejects(pki: Path, case: str) -> None:
    """No session and no data within the bounded wait when a certificate does not chain to the trusted CA (or is
    missing, or lacks a subjectAltName for 127.0.0.1)."""
    server, client, mtls = REJECTS[case]
    (p1,) = free_ports(1)
    with _sessions() as open_:
        a = open_(listen=[f"tls/127.0.0.1:{p1}"], extra=_tls(pki, server, mtls=mtls))
        b = open_(connect=[f"tls/127.0.0.1:{p1}"], extra=_tls(pki, client, mtls=mtls))
        _, got = _collect(a, _belief("*"))
        _put_for([(b, _belief(2), "forged")], NEGATIVE_WAIT)
        assert got == set()
        assert list(a.info.peers_zid()) == [] and list(b.info.peers_zid()) == []


EVERYTHING = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply"]
EVERYTHING += ["liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]


def _acl(default: str, policies: dict[str, tuple[dict[str, Any], list[str]]]) -> dict[str, Any]:
    """An ACL with rules ``team`` (allow everything on the team's keys, both ways) and ``no-inbox`` (deny ingress
    puts on any robot's inbox); ``policies``: subject id -> (subject properties, rule ids)."""
    return {
        "enabled": True,
        "default_permission": default,
        "rules": [
            {"id": "team", "permission": "allow", "messages": EVERYTHING, "key_exprs": [f"swarmloc/{TEAM}/**"]},
            {
                "id": "no-inbox",
                "permission": "deny",
                "flows": ["ingress"],
                "messages": ["put"],
                "key_exprs": [_inbox("*")],
            },
        ],
        "subjects": [{"id": sid, **props} for sid, (props, _) in policies.items()],
        "policies": [{"rules": rules, "subjects": [sid]} for sid, (_, rules) in policies.items()],
    }


CN2 = {"cert_common_names": ["robot-2"]}
ACL_CASES = {
    # case: (robot 1's ACL, mTLS, robot 2's inbox put denied)
    "common name": (_acl("allow", {"r2": (CN2, ["no-inbox"])}), True, True),
    "interface": (_acl("allow", {"lo": ({"interfaces": ["lo", "lo0"]}, ["no-inbox"])}), True, True),
    "other common name": (_acl("allow", {"r3": ({"cert_common_names": ["robot-3"]}, ["no-inbox"])}), True, False),
    "common name without mTLS": (_acl("allow", {"r2": (CN2, ["no-inbox"])}), False, False),
    "deny beats allow in one subject": (_acl("deny", {"r2": (CN2, ["team", "no-inbox"])}), True, True),
    "allow from another subject wins": (
        _acl("deny", {"anyone": ({}, ["team"]), "r2": (CN2, ["team", "no-inbox"])}),
        True,
        False,
    ),
}


@pytest.mark.parametrize("case", list(ACL_CASES))
def test_acl_deny_inbox(pki: Path, case: str) -> None:
    """Robot 1 (listening, with the ACL) receives robot 2's belief put, and its inbox put only where the ACL lets
    it through ("other common name" is the control). Two cases document limits: a common name is known to the
    listener only under mTLS, and a link matching several subjects gets through when any one of them allows (a deny
    only overrides the allows of the same subject's policies; ``{}`` is a subject matching every link)."""
    acl, mtls, denied = ACL_CASES[case]
    (p1,) = free_ports(1)
    with _sessions() as open_:
        a = open_(listen=[f"tls/127.0.0.1:{p1}"], extra={**_tls(pki, "robot-1", mtls=mtls), "access_control": acl})
        b = open_(connect=[f"tls/127.0.0.1:{p1}"], extra=_tls(pki, "robot-2", mtls=mtls))
        _, got = _collect(a, f"swarmloc/{TEAM}/robot/**")
        assert _put_until(b, _belief(2), "b", got)
        _put_for([(b, _belief(2), "b"), (b, _inbox(1), "i")], NEGATIVE_WAIT)
        expected = {(_belief(2), "b")} if denied else {(_belief(2), "b"), (_inbox(1), "i")}
        assert got == expected


def _doc_config(pki: Path, tmp_path: Path, cert: str) -> Path:
    """The TLS JSON5 block of docs/network.md with the certificate directory and robot 1's file names replaced."""
    text = DOC.read_text()
    blocks = [b for b in re.findall(r"```json5\n(.*?)\n```", text, flags=re.S) if "tls" in b]
    assert len(blocks) == 1, "docs/network.md should hold exactly one json5 block with TLS"
    conf = blocks[0].replace("/etc/swarmloc/tls/", f"{pki}/")
    conf = conf.replace("robot-1.key", f"{cert}.key").replace("robot-1.pem", f"{cert}.pem")
    path = tmp_path / f"{cert}.json5"
    path.write_text(conf)
    return path


def test_doc_config(pki: Path, tmp_path: Path) -> None:
    """docs/network.md's configuration on robot 1, robot 2, the server and an intruder (a certificate of the same CA
    under a name the ACL does not list); endpoints replaced by loopback ones. Each node enforces the ACL."""
    p1, p2, p3, p4 = free_ports(4)
    ep = [f"tls/127.0.0.1:{p}" for p in (p1, p2, p3, p4)]
    no_connect = {"connect/endpoints": []}
    q = f"swarmloc/{TEAM}/robot/%s/query"
    alive = f"swarmloc/{TEAM}/alive/%s"
    # transport/link/protocols: ["tls"] refuses a plain TCP endpoint
    tcp = zenoh_config([f"tcp/127.0.0.1:{p1}"], config_file=_doc_config(pki, tmp_path, "robot-1"), extra=no_connect)
    with pytest.raises(zenoh.ZError, match="Unsupported protocol: tcp"):
        zenoh.open(tcp).close()
    with _sessions() as open_:
        r1 = open_(listen=[ep[0]], config_file=_doc_config(pki, tmp_path, "robot-1"), extra=no_connect)
        r2 = open_(listen=[ep[1]], connect=[ep[0]], config_file=_doc_config(pki, tmp_path, "robot-2"))
        srv = open_(listen=[ep[2]], connect=[ep[0]], config_file=_doc_config(pki, tmp_path, "server"))
        bad = open_(listen=[ep[3]], connect=[ep[0]], config_file=_doc_config(pki, tmp_path, "intruder"))
        _, got = _collect(r1, f"swarmloc/{TEAM}/robot/**")
        _serve(r1, q % 1, "robot-1")
        _serve(r2, q % 2, "robot-2")
        _serve(r2, q % 3, "robot-2 as 3")  # impersonation
        _serve(srv, f"swarmloc/{TEAM}/server/query", "server")
        _serve(bad, q % 4, "intruder")
        tokens = [r2.liveliness().declare_token(alive % 2), r2.liveliness().declare_token(alive % 3)]
        tokens.append(bad.liveliness().declare_token(alive % 4))
        assert _until(lambda: len(list(r1.info.peers_zid())) == 3, CONNECT_WAIT)
        assert _put_until(r2, _belief(2), "robot-2", got)

        # robot 2: own belief and robot 1's inbox (allowed), robot 3's and robot 1's beliefs (impersonation: denied);
        # the intruder: robot 1's inbox and a belief of its own (no policy names it: denied)
        puts = [(r2, _belief(2), "robot-2"), (r2, _inbox(1), "robot-2"), (r2, _belief(3), "robot-2")]
        puts += [(r2, _belief(1), "robot-2"), (bad, _inbox(1), "intruder"), (bad, _belief(4), "intruder")]
        _put_for(puts, NEGATIVE_WAIT)
        assert got == {(_belief(2), "robot-2"), (_inbox(1), "robot-2")}

        assert _answers(r1, q % 2) == ["robot-2"]
        assert _answers(r1, q % 3) == []
        assert _answers(r1, q % 4) == []
        assert _answers(r1, f"swarmloc/{TEAM}/server/query") == ["server"]
        assert _answers(r2, q % 1) == ["robot-1"]
        assert _answers(bad, q % 1) == []
        assert sorted(str(r.ok.key_expr) for r in r1.liveliness().get(alive % "*", timeout=1.0) if r.ok) == [alive % 2]
