"""Plain UDP on the radio: existing swarm code that talks UDP runs unmodified over the simulated network.

Inside a mission process, vehicle ``i`` has the radio address ``10.42.0.(i+1)``; ``10.42.0.255`` reaches
every vehicle in range. A datagram socket bound to a port (on its radio address or on the wildcard
address) receives the radio packets sent to that port — the port is virtual, so every vehicle can bind the
same one on one machine; ``sendto`` to a radio address hands the datagram to
the network model (ENQUEUE) instead of the kernel. Timeouts (``settimeout``) are sim time. Everything else
— other addresses, TCP, MAVSDK's and asyncio's own sockets — is the real socket, untouched.

Supported: blocking ``sendto``/``recvfrom``/``recv`` with or without ``settimeout``. Not supported: radio
traffic through asyncio datagram endpoints or ``select`` (use ``harness.net.radio.receive_async``).
"""

from __future__ import annotations

import ipaddress
import socket as _socket
from typing import Any

from harness.simclock.protocol import BROADCAST
from harness.simclock.runtime import SimRuntime

RADIO_NET = ipaddress.ip_network("10.42.0.0/24")
BROADCAST_ADDR = "10.42.0.255"

_original_socket = _socket.socket
_rt: SimRuntime | None = None


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


class RadioSocket(_original_socket):
    """``socket.socket`` that routes UDP on the 10.42.0.0/24 radio network through the simulation."""

    _radio_port: int | None = None
    _sim_timeout: float | None = None

    def bind(self, address: Any) -> None:
        if _rt is not None and self.type == _socket.SOCK_DGRAM and self.family == _socket.AF_INET:
            host, port = address[0], int(address[1])
            if host in ("", "0.0.0.0") or _radio_host(host) is not None:
                # every vehicle's process shares this machine: the radio port is virtual, the kernel socket
                # gets an ephemeral loopback port so that five vehicles can all "bind" port 5005
                super().bind(("127.0.0.1", 0))
                self._radio_port = port or int(super().getsockname()[1])
                return
        super().bind(address)

    def settimeout(self, value: float | None) -> None:
        self._sim_timeout = value
        super().settimeout(value)

    def sendto(self, data: Any, *args: Any) -> int:
        address = args[-1]
        dst = _radio_host(address[0]) if isinstance(address, tuple) else None
        if dst is None or _rt is None:
            return int(super().sendto(data, *args))
        payload = bytes(data)
        _rt.queue_packet(dst, int(address[1]), payload)
        return len(payload)

    def recvfrom(self, bufsize: int, flags: int = 0) -> tuple[bytes, Any]:
        if self._radio_port is None or _rt is None:
            return super().recvfrom(bufsize, flags)
        d = _rt.take_delivery(self._radio_port, self._sim_timeout)
        if d is None:
            raise TimeoutError("timed out")  # socket.timeout is TimeoutError since Python 3.10
        return d.payload[:bufsize], (radio_address(d.src), d.port)

    def recv(self, bufsize: int, flags: int = 0) -> bytes:
        if self._radio_port is None or _rt is None:
            return super().recv(bufsize, flags)
        return self.recvfrom(bufsize, flags)[0]


def install(rt: SimRuntime) -> None:
    """Route radio-address UDP of sockets created from now on through ``rt`` (mission processes only)."""
    global _rt
    _rt = rt
    _socket.socket = RadioSocket  # type: ignore[misc]


def uninstall() -> None:
    global _rt
    _rt = None
    _socket.socket = _original_socket  # type: ignore[misc]
