"""Channel addresses and sockets: ``tcp://HOST:PORT``, ``unix:///path/to.sock`` or, on Linux, ``unix://@name``
(an abstract unix socket: no file, gone with the last process holding it, also after ``kill -9``).

Thin adapter: parses addresses, opens listening and connecting sockets with the options lockstep
traffic needs (TCP_NODELAY: every tick is a burst of small frames that must not wait for Nagle).
"""

from __future__ import annotations

import ipaddress
import os
import socket
from dataclasses import dataclass

from harness.core.errors import ScenarioError


@dataclass(frozen=True, slots=True)
class Address:
    scheme: str  # "tcp" or "unix"
    host: str = ""
    port: int = 0
    path: str = ""

    def __str__(self) -> str:
        if self.scheme == "unix":
            return f"unix://{self.path}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp://{host}:{self.port}"

    @property
    def is_abstract(self) -> bool:
        """A unix socket in Linux's abstract namespace (``unix://@name``): no file to remove."""
        return self.scheme == "unix" and self.path.startswith("@")

    @property
    def is_loopback(self) -> bool:
        if self.scheme == "unix":
            return True
        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False


def parse_address(text: str) -> Address:
    """Parse ``tcp://host:port``, ``host:port``, ``:port`` or ``unix:///path``."""
    if text.startswith("unix://"):
        path = text[len("unix://") :]
        if not path:
            raise ScenarioError(f"channel address {text!r}: a unix address needs a path (unix:///tmp/x.sock)")
        return Address("unix", path=path)
    rest = text[len("tcp://") :] if text.startswith("tcp://") else text
    host, sep, port_s = rest.rpartition(":")
    if not sep:
        raise ScenarioError(f"channel address {text!r}: expected tcp://HOST:PORT or unix:///PATH")
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_s)
    except ValueError:
        raise ScenarioError(f"channel address {text!r}: port {port_s!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise ScenarioError(f"channel address {text!r}: port {port} is out of range 0-65535")
    return Address("tcp", host=host, port=port)


def _unix_name(addr: Address) -> str:
    """The name to bind or connect: ``@name`` is Linux's abstract namespace (a leading NUL byte)."""
    return "\0" + addr.path[1:] if addr.is_abstract else addr.path


def _tune(sock: socket.socket) -> None:
    if sock.family in (socket.AF_INET, socket.AF_INET6):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


def listen(addr: Address, backlog: int = 128) -> tuple[socket.socket, Address]:
    """A listening socket for ``addr``; returns it with the address actually bound (port 0 resolved). An
    address in use (or not this machine's) is a :class:`ScenarioError`: one line, before the run starts."""
    sock: socket.socket | None = None
    try:
        if addr.scheme == "unix":
            if not addr.is_abstract and os.path.exists(addr.path):
                os.unlink(addr.path)
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.bind(_unix_name(addr))
            sock.listen(backlog)
            return sock, addr
        family = socket.AF_INET6 if ":" in addr.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((addr.host, addr.port))
        sock.listen(backlog)
    except OSError as exc:
        if sock is not None:
            sock.close()
        raise ScenarioError(
            f"{addr}: cannot listen there ({exc.strerror}): another program may hold it; choose another address"
        ) from None
    host, port = sock.getsockname()[:2]
    return sock, Address("tcp", host=host, port=port)


def connect(addr: Address, timeout_s: float = 10.0) -> socket.socket:
    """A connected, tuned, blocking socket to ``addr``."""
    if addr.scheme == "unix":
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout_s)
        sock.connect(_unix_name(addr))
    else:
        sock = socket.create_connection((addr.host, addr.port), timeout=timeout_s)
    sock.settimeout(None)
    _tune(sock)
    return sock


def accept_tuned(server: socket.socket) -> socket.socket:
    conn, _ = server.accept()
    _tune(conn)
    return conn
