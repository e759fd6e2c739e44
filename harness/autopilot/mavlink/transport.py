"""UDP links of one vehicle: the API link (to the mission script's port) and the GCS link.

Each link is one UDP socket. It always sends to its configured remote (``14540 + i`` for the API link,
``14550`` for the GCS link, like PX4 SITL) and also to every peer that sent it a valid frame
within the last ``peer_timeout_ns`` of wall time (garbage or unsigned senders are not peers) (MAVSDK forgets a UDP peer silent for 10 s; so do we).
Replies go to the address a message came from. Socket errors (ICMP port unreachable when nobody listens,
full buffers) are counted, never raised.
"""

from __future__ import annotations

import errno
import logging
import socket
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol

from harness.autopilot.mavlink.runlocal import udp_bound
from harness.core.endpoints import LISTEN_HELLO, LISTEN_HELLO_WALL
from harness.core.errors import ScenarioError

log = logging.getLogger(__name__)

Address = tuple[str, int]

PEER_TIMEOUT_NS = 10_000_000_000
LISTENERS_MAX = 64
"""Sockets announced with ``LISTEN_HELLO`` a link keeps (a mission has one or two); later ones are ignored."""
_LISTENER_CHECK_NS = 2_000_000_000
"""How often the listeners silent for ``peer_timeout_ns`` are checked for a socket still bound there."""
_RECV_SIZE = 65_535
GREET_NS = 20_000_000
"""A port announced with ``LISTEN_HELLO_WALL`` gets a heartbeat this often until it answers (MAVSDK listening
there discovers the vehicle on the first one that arrives after it has bound the port)."""
_GREET_FOR_NS = 30_000_000_000
DATAGRAM_MAX = 1400
"""Frames for one destination share a datagram up to this many bytes: under Ethernet's MTU (no IP
fragments to a GCS on another machine) and under MAVSDK's 2,048-byte receive buffer. A frame is never split."""


@dataclass(frozen=True, slots=True)
class LinkConfig:
    name: str
    local: Address
    """Address to bind; port 0 = any free port."""
    remote: Address | None
    """Where to send even before anyone has spoken to us (None: only to peers)."""


@dataclass(frozen=True, slots=True)
class PortsConfig:
    """Port plan (docs/design.md, "Ports"): vehicle ``i`` sends to ``api_port_base + i`` and to ``gcs_port``.

    ``api_port_base = 0``: the API link sends only to the peers that spoke to it (``harness run``: each
    mission connects out to its own vehicle, and no other run's listener can hear it).

    ``api_local_port_base`` / ``gcs_local_port_base``: 0 binds any free port (no collisions between
    parallel runs); otherwise the vehicle binds ``base + i`` (PX4 SITL uses 14580 and 18570), which is what
    a script that connects out (``udpout://``) needs. ``gcs_port = 0`` disables the GCS link.
    """

    api_port_base: int = 14540
    gcs_port: int = 14550
    remote_host: str = "127.0.0.1"
    bind_host: str = "127.0.0.1"
    api_local_port_base: int = 0
    gcs_local_port_base: int = 0
    gcs_extra_ports: tuple[int, ...] = ()
    """More UDP outputs like the GCS one (ArduPilot SITL users expect 14550 and 14551)."""
    tcp_port_base: int = 0
    """ArduPilot's SERIAL0: vehicle ``i`` listens on TCP ``tcp_port_base + tcp_port_step * i`` (0: no TCP)."""
    tcp_port_step: int = 1
    tcp_sim_clients: bool = False
    """The TCP clients are missions on sim time (``harness run``); ground stations connect over UDP."""

    def tcp_local(self, vehicle: int) -> Address | None:
        """The TCP address vehicle ``vehicle`` listens on, or None without a TCP link."""
        if not self.tcp_port_base:
            return None
        port = self.tcp_port_base + self.tcp_port_step * vehicle
        if not 0 < port <= 65535:
            raise ScenarioError(f"MAVLink TCP port {port} of vehicle {vehicle} is not a TCP port (1..65535)")
        return (self.bind_host, port)

    def links(self, vehicle: int) -> tuple[LinkConfig, ...]:
        if vehicle < 0:
            raise ScenarioError(f"vehicle index must be >= 0, got {vehicle}")
        for name, port in (
            ("api_port_base", self.api_port_base),
            ("gcs_port", self.gcs_port),
            ("api_local_port_base", self.api_local_port_base),
            ("gcs_local_port_base", self.gcs_local_port_base),
        ):
            if not 0 <= port <= 65535:
                raise ScenarioError(f"MAVLink port setting {name}={port} is not a UDP port (0..65535)")

        def local(base: int) -> Address:
            return (self.bind_host, base + vehicle if base else 0)

        api_remote = (self.remote_host, self.api_port_base + vehicle) if self.api_port_base else None
        links = [LinkConfig("api", local(self.api_local_port_base), api_remote)]
        if self.gcs_port:
            links.append(LinkConfig("gcs", local(self.gcs_local_port_base), (self.remote_host, self.gcs_port)))
        for i, port in enumerate(self.gcs_extra_ports):
            if not 0 < port <= 65535:
                raise ScenarioError(f"MAVLink output port {port} is not a UDP port (1..65535)")
            links.append(LinkConfig(f"gcs{i + 2}", (self.bind_host, 0), (self.remote_host, port)))
        return tuple(links)


class Link(Protocol):
    """What the server and the hub use of a link (UDP here, TCP in ``tcp.py``)."""

    name: str
    send_errors: int
    sim_sent: int
    """Datagrams (or frames) sent so far to peers on sim time: what wakes a mission waiting for MAVLink."""

    @property
    def sock(self) -> socket.socket: ...
    @property
    def local_address(self) -> Address: ...
    def receive(self, max_datagrams: int) -> Iterator[tuple[bytes, Address]]: ...
    def heard(self, peer: Address, now_ns: int) -> bool: ...
    def destinations(self, now_ns: int, sim_peers: bool = True) -> list[Address]: ...
    @property
    def has_sim_peers(self) -> bool: ...
    def is_sim_peer(self, addr: Address) -> bool: ...
    @property
    def greeting(self) -> bool: ...
    def greetings(self, now_ns: int) -> list[Address]: ...
    def send(self, data: bytes, addr: Address) -> bool: ...
    def close(self) -> None: ...


class UdpLink:
    """One non-blocking UDP socket with its remote and its recently heard peers."""

    def __init__(self, config: LinkConfig, peer_timeout_ns: int = PEER_TIMEOUT_NS) -> None:
        self.config = config
        self.name = config.name
        self.peer_timeout_ns = peer_timeout_ns
        self._peers: dict[Address, int] = {}
        self._sim_peers: set[Address] = set()
        self._greeting: dict[Address, int] = {}
        """Announced MAVSDK ports that have not spoken yet: address → wall time to give up greeting."""
        self._greeted_ns = 0
        self._last_now = 0
        """The wall time of the last ``destinations`` (a listener announced since counts as heard then)."""
        self._listeners_checked_ns = 0
        self.listeners_refused = 0
        self.send_errors = 0
        self.recv_errors = 0
        self.sim_sent = 0
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            sock.bind(config.local)
        except OSError as e:
            sock.close()
            raise ScenarioError(
                f"MAVLink {config.name} link cannot bind {config.local[0]}:{config.local[1]} ({e}); "
                "choose another port base or 0 for a free port"
            ) from None
        sock.setblocking(False)
        self.sock = sock

    @property
    def local_address(self) -> Address:
        host, port = self.sock.getsockname()[:2]
        return (host, port)

    def fileno(self) -> int:
        return self.sock.fileno()

    def receive(self, max_datagrams: int) -> Iterator[tuple[bytes, Address]]:
        """Up to ``max_datagrams`` waiting datagrams with their senders."""
        for _ in range(max_datagrams):
            try:
                data, addr = self.sock.recvfrom(_RECV_SIZE)
            except BlockingIOError:
                return
            except OSError as e:
                # ECONNREFUSED: an ICMP port-unreachable for an earlier send (nobody listens there yet).
                if e.errno != errno.ECONNREFUSED:
                    self.recv_errors += 1
                    log.debug("%s link: receive error %s", self.name, e)
                continue
            if data == LISTEN_HELLO:  # a mission's listening socket (pymavlink udpin): it gets what peers get
                peer = (addr[0], addr[1])
                if peer not in self._sim_peers and len(self._sim_peers) >= LISTENERS_MAX:
                    self.listeners_refused += 1
                    continue
                self._peers[peer] = max(self._peers.get(peer, 0), self._last_now)
                self._sim_peers.add(peer)
                continue
            if data == LISTEN_HELLO_WALL:  # the port a mission's MAVSDK is about to listen on (mavsdk_url):
                # greeted with heartbeats until it answers, and a peer from then on (what went there before
                # MAVSDK had bound it would be lost, unlike the same seed's next run)
                self._greeting[(addr[0], addr[1])] = -1
                continue
            yield data, (addr[0], addr[1])

    def heard(self, peer: Address, now_ns: int) -> bool:
        """``peer`` sent a valid (and, with signing, correctly signed) frame: telemetry goes there too.
        True when it is a new peer."""
        new = peer not in self._peers
        self._peers[peer] = max(self._peers.get(peer, 0), now_ns)
        self._greeting.pop(peer, None)
        return new

    @property
    def greeting(self) -> bool:
        """Whether an announced MAVSDK port waits for its first heartbeat (the server wakes every GREET_NS)."""
        return bool(self._greeting)

    def greetings(self, now_ns: int) -> list[Address]:
        """The announced ports to greet now (each ``GREET_NS`` until it speaks, for at most 30 s)."""
        if not self._greeting or now_ns - self._greeted_ns < GREET_NS:
            return []
        self._greeted_ns = now_ns
        for addr, until in list(self._greeting.items()):
            if until < 0:
                self._greeting[addr] = now_ns + _GREET_FOR_NS
            elif now_ns > until:
                del self._greeting[addr]
        return list(self._greeting)

    def destinations(self, now_ns: int, sim_peers: bool = True) -> list[Address]:
        """The remote and the live peers (forgets peers silent longer than the timeout); without the peers that
        live on sim time (missions' sockets, which announced themselves) when ``sim_peers`` is False."""
        self._last_now = now_ns
        stale = [a for a, t in self._peers.items() if now_ns - t > self.peer_timeout_ns and a not in self._sim_peers]
        for a in stale:
            del self._peers[a]
            log.info("%s link: forgot peer %s:%d (silent for over %.0f s)", self.name, *a, self.peer_timeout_ns / 1e9)
        if self._sim_peers and now_ns - self._listeners_checked_ns > _LISTENER_CHECK_NS:
            self._listeners_checked_ns = now_ns
            self._forget_closed_listeners(now_ns)
        dests = list(self._peers) if sim_peers else [a for a in self._peers if a not in self._sim_peers]
        remote = self.config.remote
        if remote is not None and remote not in self._peers:
            dests.append(remote)
        return dests

    def _forget_closed_listeners(self, now_ns: int) -> None:
        """A listener may be silent for the whole run (it only listens), so silence alone does not end it: one
        silent for ``peer_timeout_ns`` whose socket is no longer bound (its mission ended, or a process that
        announced a thousand and left) is forgotten. Where ``/proc`` cannot say, listeners stay."""
        silent = [a for a in self._sim_peers if now_ns - self._peers.get(a, 0) > self.peer_timeout_ns]
        if not silent:
            return
        bound = udp_bound()
        if bound is None:
            return
        for a in silent:
            if a not in bound and ("0.0.0.0", a[1]) not in bound and ("::", a[1]) not in bound:
                self._sim_peers.discard(a)
                self._peers.pop(a, None)
                log.info("%s link: forgot listener %s:%d (its socket is closed)", self.name, *a)

    @property
    def has_sim_peers(self) -> bool:
        """Whether a peer that lives on sim time (a mission's Python socket) listens on this link."""
        return bool(self._sim_peers)

    def is_sim_peer(self, addr: Address) -> bool:
        """Whether ``addr`` is a mission's socket on sim time (it announced itself with ``LISTEN_HELLO``)."""
        return addr in self._sim_peers

    def peers(self) -> list[Address]:
        return list(self._peers)

    def send(self, data: bytes, addr: Address) -> bool:
        try:
            self.sock.sendto(data, addr)
            if addr in self._sim_peers:
                self.sim_sent += 1
            return True
        except OSError as e:
            if e.errno != errno.ECONNREFUSED:
                self.send_errors += 1
                log.debug("%s link: send to %s:%d failed: %s", self.name, addr[0], addr[1], e)
            return False

    def close(self) -> None:
        self.sock.close()


def pack_frames(frames: list[bytes], limit: int = DATAGRAM_MAX) -> Iterator[tuple[bytes, int]]:
    """``frames`` joined, in order, into datagrams of at most ``limit`` bytes (a larger frame goes alone),
    each with the number of frames in it. MAVLink receivers parse every frame of a datagram (MAVSDK,
    pymavlink, QGroundControl, MAVProxy; ArduPilot's UDP ports send them so)."""
    if len(frames) == 1:
        yield frames[0], 1
        return
    batch: list[bytes] = []
    size = 0
    for f in frames:
        if batch and size + len(f) > limit:
            yield b"".join(batch), len(batch)
            batch, size = [], 0
        batch.append(f)
        size += len(f)
    if batch:
        yield b"".join(batch), len(batch)
