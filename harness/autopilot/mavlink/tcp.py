"""A TCP MAVLink link: ArduPilot SITL's SERIAL0 (``tcp:127.0.0.1:5760``), any number of clients at once.

The hub serves links by ``select()`` on one socket each and reads datagrams from it. A TCP link keeps that
shape: a small reader thread accepts clients, cuts each client's byte stream into whole MAVLink frames
(:func:`take_frames`) and passes every frame, tagged with its client's address, through a local datagram
socket pair whose read end is the link's ``sock``. Replies go straight to the client's TCP socket;
telemetry goes to every connected client. A client that closes, resets, or does not take its data within
``send_timeout_s`` is dropped (a partial frame would corrupt its stream).
"""

from __future__ import annotations

import contextlib
import logging
import select
import selectors
import socket
import struct
import threading
from collections.abc import Iterator

from harness.autopilot.mavlink.transport import Address
from harness.core.errors import ScenarioError

log = logging.getLogger(__name__)

_V1, _V2 = 0xFE, 0xFD
_SIGNED = 0x01
_MAX_BUFFER = 1 << 16
_TAG = struct.Struct("!4sH")


def take_frames(buf: bytearray) -> list[bytes]:
    """Remove and return the complete MAVLink 1/2 frames at the start of ``buf`` (bytes before a start
    marker are dropped; an incomplete frame stays for the next read)."""
    out: list[bytes] = []
    while buf:
        starts = [i for i in (buf.find(_V2), buf.find(_V1)) if i >= 0]
        if not starts:
            buf.clear()
            break
        del buf[: min(starts)]
        if len(buf) < 3:
            break
        n = buf[1]
        total = n + 8 if buf[0] == _V1 else n + 12 + (13 if buf[2] & _SIGNED else 0)
        if len(buf) < total:
            break
        out.append(bytes(buf[:total]))
        del buf[:total]
    return out


class TcpLink:
    """A listening TCP socket with its clients, served through the hub like a UDP link."""

    def __init__(self, name: str, local: Address, send_timeout_s: float = 1.0, sim_clients: bool = False) -> None:
        self.name = name
        self.sim_clients = sim_clients
        """Clients live on sim time (``harness run``: the missions): what goes out on the wall clock only (the
        1 Hz wall heartbeat, wall-rate telemetry) is not sent to them, so the same seed gives the same flight."""
        self.send_timeout_s = send_timeout_s
        self.send_errors = 0
        self.sim_sent = 0
        self.recv_errors = 0
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind(local)
            listener.listen(16)
        except OSError as e:
            listener.close()
            raise ScenarioError(
                f"MAVLink {name} link cannot listen on TCP {local[0]}:{local[1]} ({e}); "
                "another simulator may hold it: stop it or choose other ports"
            ) from None
        self._listener = listener
        self.sock, self._feed = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self._feed.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        self._clients: dict[Address, socket.socket] = {}
        self._heard: set[Address] = set()
        self._lock = threading.Lock()
        self._io_lock = threading.Lock()
        """Serialises reading the clients (reader thread, and ``drain`` on the hub thread)."""
        self._buffers: dict[Address, bytearray] = {}
        self._stop_r, self._stop_w = socket.socketpair()
        self._thread = threading.Thread(target=self._run, name=f"mavlink-tcp-{self.local_address[1]}", daemon=True)
        self._thread.start()

    @property
    def local_address(self) -> Address:
        host, port = self._listener.getsockname()[:2]
        return (host, port)

    def fileno(self) -> int:
        return self.sock.fileno()

    # ------------------------------------------------------------------ reader thread
    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._listener, selectors.EVENT_READ, None)
        sel.register(self._stop_r, selectors.EVENT_READ, "stop")
        buffers = self._buffers
        try:
            while True:
                for key, _ in sel.select():
                    if key.data == "stop":
                        return
                    if key.data is None:
                        self._accept(sel, buffers)
                    else:
                        self._read(sel, key.fileobj, key.data, buffers)  # type: ignore[arg-type]
        except Exception:
            log.exception("%s link: reader thread failed", self.name)
        finally:
            for key in list(sel.get_map().values()):
                if key.data not in (None, "stop"):
                    with contextlib.suppress(OSError):
                        key.fileobj.close()  # type: ignore[union-attr]
            sel.close()

    def _accept(self, sel: selectors.BaseSelector, buffers: dict[Address, bytearray]) -> None:
        try:
            conn, raw = self._listener.accept()
        except OSError:
            return
        addr: Address = (raw[0], raw[1])
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(self.send_timeout_s)
        buffers[addr] = bytearray()
        with self._lock:
            self._clients[addr] = conn
        sel.register(conn, selectors.EVENT_READ, addr)
        log.info("%s link: client %s:%d connected", self.name, *addr)

    def _read(
        self, sel: selectors.BaseSelector, conn: socket.socket, addr: Address, buffers: dict[Address, bytearray]
    ) -> None:
        with self._io_lock:
            try:
                if not select.select([conn], [], [], 0)[0]:
                    return  # ``drain`` took it
                data = conn.recv(65536)
            except (BlockingIOError, TimeoutError):
                return
            except (OSError, ValueError):  # reset, or shut down by ``_drop`` after a failed send
                data = b""
            if data:
                self._frames(addr, data)
                return
        with contextlib.suppress(KeyError, ValueError, OSError):
            sel.unregister(conn)
        buffers.pop(addr, None)
        self._drop(addr, "closed the connection")
        with contextlib.suppress(OSError):
            conn.close()  # only the reader thread closes a client socket (its selector still holds it until now)

    def drain(self) -> None:
        """Pass on, now, every frame the clients have sent so far (the hub thread, before it confirms to a
        mission that all it sent is handled: over loopback, what a client sent is in our socket already)."""
        with self._lock:
            clients = list(self._clients.items())
        with self._io_lock:
            for addr, conn in clients:
                try:
                    while select.select([conn], [], [], 0)[0]:
                        data = conn.recv(65536)
                        if not data:
                            break  # the reader thread sees the end and drops the client
                        self._frames(addr, data)
                except (OSError, ValueError):
                    continue

    def _frames(self, addr: Address, data: bytes) -> None:
        buf = self._buffers.get(addr)
        if buf is None:
            return
        buf += data
        tag = _TAG.pack(socket.inet_aton(addr[0]), addr[1])
        for frame in take_frames(buf):
            try:
                self._feed.send(tag + frame)
            except OSError:
                self.recv_errors += 1
        if len(buf) > _MAX_BUFFER:
            buf.clear()

    def _drop(self, addr: Address, why: str) -> None:
        with self._lock:
            conn = self._clients.pop(addr, None)
            self._heard.discard(addr)
        if conn is not None:
            log.info("%s link: client %s:%d %s", self.name, addr[0], addr[1], why)
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)  # the reader thread sees the end, unregisters and closes it

    # ------------------------------------------------------------------ the hub's side
    def receive(self, max_datagrams: int) -> Iterator[tuple[bytes, Address]]:
        for _ in range(max_datagrams):
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                return
            except OSError:
                self.recv_errors += 1
                return
            ip, port = _TAG.unpack_from(data)
            yield data[_TAG.size :], (socket.inet_ntoa(ip), port)

    def heard(self, peer: Address, now_ns: int) -> bool:
        """Connected clients are peers for as long as they stay connected; True for a client's first frame."""
        with self._lock:
            new = peer in self._clients and peer not in self._heard
            if new:
                self._heard.add(peer)
            return new

    @property
    def greeting(self) -> bool:
        """TCP clients speak first: nobody to greet."""
        return False

    def greetings(self, now_ns: int) -> list[Address]:
        return []

    @property
    def has_sim_peers(self) -> bool:
        """Whether a client on sim time is connected (the run's missions)."""
        if not self.sim_clients:
            return False
        with self._lock:
            return bool(self._clients)

    def is_sim_peer(self, addr: Address) -> bool:
        """Whether the clients of this link live on sim time (the run's missions)."""
        return self.sim_clients

    def destinations(self, now_ns: int, sim_peers: bool = True) -> list[Address]:
        """Every connected client; none for wall-clock traffic (``sim_peers`` False) when the clients are on
        sim time."""
        if self.sim_clients and not sim_peers:
            return []
        with self._lock:
            return list(self._clients)

    def peers(self) -> list[Address]:
        return self.destinations(0)

    def send(self, data: bytes, addr: Address) -> bool:
        with self._lock:
            conn = self._clients.get(addr)
        if conn is None:
            return False
        try:
            conn.sendall(data)
            if self.sim_clients:
                self.sim_sent += 1
            return True
        except OSError as e:
            self.send_errors += 1
            self._drop(addr, f"dropped: send failed ({e})")
            return False

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._stop_w.send(b"\0")
        if self._thread is not threading.current_thread():
            self._thread.join(2.0)
        with self._lock:
            clients, self._clients = list(self._clients.values()), {}
        for s in (*clients, self._listener, self.sock, self._feed, self._stop_r, self._stop_w):
            with contextlib.suppress(OSError):
                s.close()
