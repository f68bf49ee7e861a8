"""The cyclonedds XML configuration of a swarmloc DDS participant, by discovery scope.

``scope="localhost"`` follows what rmw_cyclonedds does for ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
(``rmw_node.cpp``, ``check_create_domain``): multicast off (``General/AllowMulticast false``), the local host as the
one static discovery peer (``Discovery/Peers``), participant indices ``auto`` up to 32 (``ParticipantIndex``,
``MaxAutoParticipantIndex``), so discovery is unicast to the 32 well-known ports on this host. swarmloc goes one step
further than rmw_cyclonedds and binds the participant to the loopback interface only (``General/Interfaces``,
``NetworkInterface address="127.0.0.1"``): its locators are 127.0.0.1, so nothing off this host can reach it even
when it knows the ports. ``endpoints`` (static peers, like ``ROS_STATIC_PEERS``) must then be loopback addresses.

``scope="subnet"``: cyclonedds' normal SPDP multicast discovery on its default interface, plus ``endpoints`` as
static unicast peers (rmw_cyclonedds' ``SUBNET``).

Both set ``Internal/MaxSampleSize`` (the largest serialized sample cyclonedds reassembles or sends, in either
direction) to a multiple of the middleware's ``max_bytes``: memory is bounded before any sample reaches Python,
where samples over ``max_bytes`` are refused and counted.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence
from xml.sax.saxutils import quoteattr

LOOPBACK = "127.0.0.1"
MAX_AUTO_PARTICIPANT_INDEX = 32  # rmw_cyclonedds' value
REASSEMBLY_FACTOR = 4  # cyclonedds drops (uncounted) samples over this many times max_bytes


def _peer(address: str, localhost: bool) -> str:
    host = address.rsplit(":", 1)[0] if address.count(":") == 1 else address
    if not host or any(c in host for c in "<>\"'& "):
        raise ValueError(f"endpoint {address!r} is not a host address (host or host:port)")
    if localhost:
        try:
            loop = host == "localhost" or ipaddress.ip_address(host.strip("[]")).is_loopback
        except ValueError:
            loop = False
        if not loop:
            raise ValueError(f"scope 'localhost' takes loopback endpoints only, got {address!r}")
    return f"<Peer address={quoteattr(address)}/>"


def dds_config(scope: str, endpoints: Sequence[str] = (), max_bytes: int = 1 << 20) -> str:
    """The ``<CycloneDDS>`` XML for ``scope`` (``"localhost"`` or ``"subnet"``; module docstring)."""
    if scope not in ("localhost", "subnet"):
        raise ValueError(f"scope must be 'localhost' or 'subnet', got {scope!r}")
    if isinstance(endpoints, str):
        raise ValueError(f"endpoints must be a sequence of addresses, got the string {endpoints!r}")
    local = scope == "localhost"
    peers = [_peer(str(e), local) for e in endpoints]
    general = ""
    discovery = f"<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>{MAX_AUTO_PARTICIPANT_INDEX}"
    discovery += "</MaxAutoParticipantIndex>"
    if local:
        general = f'<Interfaces><NetworkInterface address="{LOOPBACK}"/></Interfaces>'
        general += "<AllowMulticast>false</AllowMulticast>"
        peers = [f'<Peer address="{LOOPBACK}"/>', *peers]
    if peers:
        discovery += "<Peers>" + "".join(peers) + "</Peers>"
    internal = f"<MaxSampleSize>{int(max_bytes) * REASSEMBLY_FACTOR}B</MaxSampleSize>"
    return (f"<CycloneDDS><Domain><General>{general}</General><Discovery>{discovery}</Discovery>"
            f"<Internal>{internal}</Internal></Domain></CycloneDDS>")  # fmt: skip
