"""Plain UDP on the radio: existing swarm code that talks UDP runs unmodified over the simulated network.

Inside a mission process, vehicle ``i`` has the radio address ``10.42.0.(i+1)``; ``10.42.0.255`` reaches
every vehicle in range. A datagram socket bound to a port (on its radio address or on the wildcard
address) receives the radio packets sent to that port — the port is virtual, so every vehicle can bind the
same one on one machine; ``sendto`` to a radio address hands the datagram to
the network model (ENQUEUE) instead of the kernel. Timeouts (``settimeout``) are sim time. Everything else
— other addresses, TCP, MAVSDK's and asyncio's own sockets — is the real socket, untouched.

Radio sockets block, time out and poll (``select``, non-blocking) on the sim clock like every socket of a
mission (:mod:`harness.simclock.simsocket`); a socket bound to the wildcard address gets both radio packets and
real datagrams. Not supported: radio traffic through asyncio datagram endpoints (use
``harness.net.radio.receive_async``).
"""

from __future__ import annotations

import ipaddress
from typing import Any

from harness.core.endpoints import VehicleEndpoints, udp_listen_redirected
from harness.simclock import simsocket
from harness.simclock.installed import INSTALLED
from harness.simclock.runtime import SimRuntime
from harness.simclock.simsocket import SimSocket
from harness.wire.protocol import BROADCAST

_original_socket = simsocket._original_socket

RADIO_NET = ipaddress.ip_network("10.42.0.0/24")
BROADCAST_ADDR = "10.42.0.255"


def radio_address(vehicle: int) -> str:
    return f"10.42.0.{vehicle + 1}"


def _radio_host(host: Any) -> int | None:
    """The vehicle a radio address names (BROADCAST for .255), or None for any other address."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return None
    if ip not in RADIO_NET:
        return None
    last = int(ip) & 0xFF
    return BROADCAST if last == 255 else last - 1


class RadioSocket(SimSocket):
    """A mission's socket that also reaches the 10.42.0.0/24 radio network through the simulation."""

    _radio_port: int | None = None

    def bind(self, address: Any) -> None:
        if INSTALLED.sockets is not None and self._is_inet_dgram() and isinstance(address, tuple):
            host, port = address[0], int(address[1])
            wildcard = host in ("", "0.0.0.0") and not udp_listen_redirected(host, port)
            if wildcard or _radio_host(host) is not None:
                # every vehicle's process shares this machine: the radio port is virtual, the kernel socket
                # gets an ephemeral loopback port so that five vehicles can all "bind" port 5005
                _original_socket.bind(self, ("127.0.0.1", 0))
                self._radio_port = port or int(self.getsockname()[1])
                return
        super().bind(address)

    def sendto(self, data: Any, *args: Any) -> int:
        address = args[-1]
        dst = _radio_host(address[0]) if isinstance(address, tuple) else None
        rt = INSTALLED.sockets
        if dst is None or rt is None:
            return super().sendto(data, *args)
        payload = bytes(data)
        rt.queue_packet(dst, int(address[1]), payload)
        return len(payload)

    def _sim_ready(self) -> bool:
        rt = INSTALLED.sockets
        return self._radio_port is not None and rt is not None and rt.mail.has(self._radio_port)

    def _waits_on_inbox(self) -> bool:
        return self._radio_port is not None

    def recvfrom(self, bufsize: int, flags: int = 0) -> tuple[bytes, Any]:
        rt, port = INSTALLED.sockets, self._radio_port
        if port is None or rt is None:
            return super().recvfrom(bufsize, flags)

        def radio_or_kernel() -> tuple[bytes, Any]:
            d = rt.mail.pop(port)
            if d is not None:
                return d.payload[:bufsize], (radio_address(d.src), d.port)
            return _original_socket.recvfrom(self, bufsize, flags)

        return self._blocking(radio_or_kernel)

    def recv(self, bufsize: int, flags: int = 0) -> bytes:
        if self._radio_port is None or INSTALLED.sockets is None:
            return super().recv(bufsize, flags)
        return self.recvfrom(bufsize, flags)[0]


def install(rt: SimRuntime, ep: VehicleEndpoints | None = None) -> None:
    """Sockets created from now on are :class:`RadioSocket` (mission processes only)."""
    simsocket.install(rt, ep, RadioSocket)


def uninstall() -> None:
    simsocket.uninstall()
