"""``socket.socket`` in a mission process: blocking calls wait on the sim clock, MAVLink goes to the vehicle.

Installed as ``socket.socket`` for the sockets a script creates (``harness mission`` does it, after its own
connection to the channel exists). The kernel socket underneath is always non-blocking; what the script set
(``settimeout``, ``setblocking``) is kept and honoured, as the socket docs say — ``settimeout(0)`` and
``setblocking(False)`` raise ``BlockingIOError`` at once, a timeout is sim time and raises ``TimeoutError``,
and ``None`` blocks (idle for the sim clock) until data comes.

MAVLink addresses are mapped to the mission's own vehicle (:mod:`harness.core.endpoints`):

- a UDP socket bound to a port scripts listen on (14540, 14550, 14551 on a local or wildcard address) is
  bound to a free loopback port instead and announces itself to its vehicle (one ``LISTEN_HELLO``
  datagram), which then sends it everything it sends its mission — pymavlink's ``udpin:0.0.0.0:14540``,
  DroneKit's ``connect("127.0.0.1:14550")``;
- ``sendto`` / ``connect`` to a local 14540/14550/14551/14580 go to the vehicle's UDP port, and a TCP
  connection to local port 5760 (ArduPilot SITL's SERIAL0) to the vehicle's TCP port.
"""

from __future__ import annotations

import _thread
import errno
import os
import socket as _socket
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from harness.core.clock import NS_PER_S, WALL
from harness.core.endpoints import (
    LISTEN_HELLO,
    LISTEN_HELLO_WALL,
    SETTLE_PREFIX,
    VehicleEndpoints,
    tcp_destination,
    team_from_env,
    team_member,
    udp_destination,
    udp_listen_redirected,
)
from harness.simclock import iowait
from harness.simclock.installed import INSTALLED
from harness.simclock.runtime import SimRuntime

_original_socket = _socket.socket
_T = TypeVar("_T")


class SimSocket(_original_socket):
    """A socket whose blocking calls are sim-time waits and whose MAVLink addresses reach the vehicle."""

    def __init__(self, family: Any = -1, type: Any = -1, proto: int = -1, fileno: int | None = None) -> None:
        super().__init__(family, type, proto, fileno)
        self._user_timeout: float | None = super().gettimeout()
        if INSTALLED.sockets is not None:
            super().settimeout(0.0)  # the kernel side never blocks; waits are the sim clock's

    # -- timeouts ------------------------------------------------------------------------------

    def _timeout(self) -> float | None:
        return self._user_timeout

    def settimeout(self, value: float | None) -> None:
        if value is not None and value < 0:
            raise ValueError("Timeout value out of range")
        self._user_timeout = None if value is None else float(value)
        super().settimeout(0.0 if INSTALLED.sockets is not None else value)

    def gettimeout(self) -> float | None:
        return self._timeout()

    def setblocking(self, flag: bool) -> None:
        self.settimeout(None if flag else 0.0)

    def _blocking(self, op: Callable[[], _T], write: bool = False) -> _T:
        """Run a non-blocking ``op`` until it succeeds, waiting on the sim clock in between."""
        timeout = self._timeout()
        rt = INSTALLED.sockets
        if rt is None or timeout == 0.0:
            return op()
        if not rt.on_sim_time():  # a harness thread: the original blocking behaviour on the wall clock
            while True:
                try:
                    return op()
                except (BlockingIOError, InterruptedError):
                    r, w, _ = iowait.real_select([] if write else [self], [self] if write else [], [], timeout)
                    if not (r or w):
                        raise TimeoutError("timed out") from None
        deadline = iowait.deadline_of(rt, timeout)
        while True:
            try:
                return op()
            except (BlockingIOError, InterruptedError):
                pass
            ready = self._sim_ready()
            if ready:
                continue
            if rt.closed or (deadline is not None and rt.now_ns() >= deadline):
                raise TimeoutError("timed out")
            fd = self.fileno()
            iowait.wait(rt, [] if write else [fd], [fd] if write else [], deadline, inbox=self._waits_on_inbox())

    def _sim_ready(self) -> bool:
        """Data the runtime holds for this socket (radio packets); see ``harness.simclock.udp``."""
        return False

    def _waits_on_inbox(self) -> bool:
        return False

    # -- MAVLink addresses -----------------------------------------------------------------------

    def _is_inet_dgram(self) -> bool:
        return self.family == _socket.AF_INET and self.type == _socket.SOCK_DGRAM

    _mavlink = False

    def _mark_mavlink(self) -> None:
        """This socket talks to the vehicle: its waits follow every phase, its sends are settled."""
        self._mavlink = True
        rt = INSTALLED.sockets
        if rt is not None:
            rt.mavlink_fds.add(self.fileno())

    def _sent(self) -> None:
        rt = INSTALLED.sockets
        if self._mavlink and rt is not None:
            rt.mavlink_sent += 1
            rt.clock_read()  # a thread that only ever sends (no wait, no answer read) sees time pass

    def _held(self, data: Any, flags: int, address: Any) -> bool:
        """MAVLink a script thread sends its vehicle in phase 0 waits in :data:`OUTBOX` for the phase's next settle,
        which sends it (in order) while the script is idle: the vehicle's answers reach the script only then, never
        while its threads run. A reader that polls its socket without waiting saw an answer or not yet, as the
        machine's pace had it (DroneKit's reader sent its 1 Hz heartbeat after the first or the second ACK of a
        phase, and the vehicle's budget of the loop then answered one command more or less)."""
        rt = INSTALLED.sockets
        if not (self._mavlink and rt is not None and rt.settle_mavlink is not None and rt.on_sim_time()):
            return False
        error, self._send_error = self._send_error, None
        if error is not None:
            raise error  # what the settle's send met, told at the next send as the kernel would have
        OUTBOX.add(self, bytes(memoryview(data).cast("B")), flags, address)
        self._sent()
        return True

    _send_error: OSError | None = None

    def close(self) -> None:
        rt = INSTALLED.sockets
        if self._mavlink and rt is not None:
            OUTBOX.flush()  # what was sent before ``close`` is delivered, as the kernel would (in order, all of it)
            rt.mavlink_fds.discard(self.fileno())
        super().close()

    def _map_udp(self, address: Any) -> Any:
        if not (self._is_inet_dgram() and isinstance(address, tuple)):
            return address
        if INSTALLED.endpoints is not None:
            dst = udp_destination(address[0], int(address[1]), INSTALLED.endpoints)
            if dst is not None:
                self._mark_mavlink()
                return dst
        elif not self._mavlink and team_member("udp", address[0], int(address[1]), INSTALLED.team) is not None:
            self._mark_mavlink()  # a swarm mission's datagram to one of its vehicles: settled, as any mission's
        return address

    def bind(self, address: Any) -> None:
        ep = INSTALLED.endpoints
        if (
            ep is not None
            and self._is_inet_dgram()
            and isinstance(address, tuple)
            and udp_listen_redirected(address[0], int(address[1]))
        ):
            # pymavlink sets SO_REUSEADDR on a listening socket; Linux may then hand port 0 a port another such
            # socket holds (two missions would share it): bind the free port without it
            self.setsockopt(_socket.SOL_SOCKET, _socket.SO_REUSEADDR, 0)
            super().bind(("127.0.0.1", 0))
            super().sendto(LISTEN_HELLO, (ep.host, ep.udp_port))
            self._mark_mavlink()
            self._sent()  # settled like any MAVLink: the vehicle sends to it from the next tick on, at any pace
            return
        super().bind(address)

    def connect(self, address: Any) -> None:
        ep = INSTALLED.endpoints
        if ep is not None and isinstance(address, tuple) and self.family == _socket.AF_INET:
            if self.type == _socket.SOCK_STREAM:
                dst = tcp_destination(address[0], int(address[1]), ep)
                if dst is not None:
                    address = dst
                    self._mark_mavlink()
            else:
                address = self._map_udp(address)
        elif INSTALLED.team and isinstance(address, tuple) and self.family == _socket.AF_INET:
            if self.type == _socket.SOCK_STREAM:
                if team_member("tcp", address[0], int(address[1]), INSTALLED.team) is not None:
                    self._mark_mavlink()
            else:
                address = self._map_udp(address)
        if self.type != _socket.SOCK_STREAM or INSTALLED.sockets is None or self._timeout() == 0.0:
            super().connect(address)
            return
        err = super().connect_ex(address)
        if err in (0, errno.EISCONN):
            return
        if err not in (errno.EINPROGRESS, errno.EALREADY, errno.EWOULDBLOCK, errno.EAGAIN):
            raise OSError(err, os.strerror(err))

        def check() -> None:
            e = self.getsockopt(_socket.SOL_SOCKET, _socket.SO_ERROR)
            if e == 0:
                if not iowait.real_select([], [self], [], 0)[1]:
                    raise BlockingIOError
                return
            raise OSError(e, os.strerror(e))

        self._blocking(check, write=True)

    def connect_ex(self, address: Any) -> int:
        try:
            self.connect(address)
        except OSError as e:
            return e.errno or errno.EIO
        return 0

    # -- blocking calls ---------------------------------------------------------------------------

    def recv(self, bufsize: int, flags: int = 0) -> bytes:
        return self._blocking(lambda: _original_socket.recv(self, bufsize, flags))

    def recvfrom(self, bufsize: int, flags: int = 0) -> tuple[bytes, Any]:
        return self._blocking(lambda: _original_socket.recvfrom(self, bufsize, flags))

    def recv_into(self, buffer: Any, nbytes: int = 0, flags: int = 0) -> int:
        return self._blocking(lambda: _original_socket.recv_into(self, buffer, nbytes, flags))

    def recvfrom_into(self, buffer: Any, nbytes: int = 0, flags: int = 0) -> tuple[int, Any]:
        return self._blocking(lambda: _original_socket.recvfrom_into(self, buffer, nbytes, flags))

    def accept(self) -> tuple[Any, Any]:
        return self._blocking(lambda: _original_socket.accept(self))

    def send(self, data: Any, flags: int = 0) -> int:
        if self._held(data, flags, None):
            return len(memoryview(data).cast("B"))
        n = self._blocking(lambda: _original_socket.send(self, data, flags), write=True)
        self._sent()
        return n

    def sendall(self, data: Any, flags: int = 0) -> None:
        view = memoryview(data).cast("B")
        while view:
            n = self.send(view, flags)
            view = view[n:]

    def sendto(self, data: Any, *args: Any) -> int:
        *flags, address = args
        address = self._map_udp(address)
        if self._held(data, flags[0] if flags else 0, address):
            return len(memoryview(data).cast("B"))
        raw_sendto: Any = _original_socket.sendto
        n = self._blocking(lambda: int(raw_sendto(self, data, *flags, address)), write=True)
        self._sent()
        return n


class _Outbox:
    """The MAVLink script threads sent their vehicles since the last settle (``SimSocket._held``), in order."""

    SEND_PATIENCE_S = 5.0
    """How long (wall clock) a settle waits for room in a TCP socket's buffer before it gives up on that socket."""

    def __init__(self) -> None:
        self._lock = _thread.allocate_lock()
        self._items: list[tuple[SimSocket, bytes, int, Any]] = []

    def add(self, sock: SimSocket, data: bytes, flags: int, address: Any) -> None:
        with self._lock:
            self._items.append((sock, data, flags, address))

    def flush(self) -> None:
        """Send everything held (the settle, before its token): what fails is told at the socket's next send."""
        with self._lock:
            items, self._items = self._items, []
        for sock, data, flags, address in items:
            if sock._send_error is not None or sock.fileno() < 0:
                continue
            try:
                if address is None:
                    self._send_all(sock, data, flags)
                else:
                    _original_socket.sendto(sock, data, flags, address)
            except OSError as e:
                sock._send_error = e

    def _send_all(self, sock: SimSocket, data: bytes, flags: int) -> None:
        view = memoryview(data)
        deadline = WALL.now_ns() + int(self.SEND_PATIENCE_S * NS_PER_S)
        while view:
            try:
                view = view[_original_socket.send(sock, view, flags) :]
            except BlockingIOError:
                if not iowait.real_select([], [sock], [], max(0, deadline - WALL.now_ns()) / NS_PER_S)[1]:
                    raise TimeoutError("the vehicle took no data for 5 s") from None


OUTBOX = _Outbox()


class _Settler:
    """Asks the vehicles to confirm that they have handled the script's MAVLink (``SimRuntime.settle_mavlink``):
    the mission's one vehicle, or every vehicle of a swarm mission (each gets the token; all must echo it).

    A loaded machine can take seconds to schedule the vehicle's MAVLink thread, so it waits up to
    ``PATIENCE_S`` of wall time; after an unanswered request it waits only ``IMPATIENCE_S`` until the vehicles
    answer again (a vehicle that is gone does not hold every phase for long: the run ends on its own)."""

    PATIENCE_S = 20.0
    IMPATIENCE_S = 0.5

    def __init__(self, eps: Sequence[VehicleEndpoints]) -> None:
        self._dsts = [(ep.host, ep.udp_port) for ep in eps]
        self._sock = _original_socket(_socket.AF_INET, _socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self._sock.setblocking(False)
        self._seq = 0
        self._answered = True

    def __call__(self) -> bool:
        OUTBOX.flush()
        self._seq += 1
        token = SETTLE_PREFIX + str(self._seq).encode()
        for dst in self._dsts:
            self._sock.sendto(token, dst)
        waiting = set(self._dsts)
        deadline = WALL.now_ns() + int((self.PATIENCE_S if self._answered else self.IMPATIENCE_S) * NS_PER_S)
        while waiting:
            r, _, _ = iowait.real_select([self._sock], [], [], max(0, deadline - WALL.now_ns()) / NS_PER_S)
            if not r:
                self._answered = False
                return False
            try:
                data, addr = self._sock.recvfrom(64)
            except OSError:
                continue
            if data == token:  # an older token is a late answer to a request that timed out
                waiting.discard((addr[0], addr[1]))
        self._answered = True
        return True


def install(rt: SimRuntime, ep: VehicleEndpoints | None, cls: type[SimSocket] = SimSocket) -> None:
    """Sockets created from now on are ``cls`` (mission processes only). Without ``ep`` (a swarm mission), the
    vehicles of ``HARNESS_VEHICLES`` are the mission's team (``INSTALLED.team``)."""
    team = () if ep is not None else tuple(team_from_env())
    INSTALLED.sockets, INSTALLED.endpoints, INSTALLED.team = rt, ep, team
    if ep is not None or team:
        rt.settle_mavlink = _Settler([ep] if ep is not None else team)
    _socket.socket = cls  # type: ignore[misc]


def uninstall() -> None:
    INSTALLED.sockets = INSTALLED.endpoints = None
    INSTALLED.team = ()
    _socket.socket = _original_socket  # type: ignore[misc]


def announce_listen_port(ep: VehicleEndpoints, sim_clock: bool = False) -> int:
    """A loopback UDP port for a MAVSDK connection to listen on (``endpoints.mavsdk_url``), announced to the
    vehicle. Reserved by a socket without ``SO_REUSEADDR``, which no port-0 bind can be given while it holds
    it, and freed just before MAVSDK binds it.

    ``sim_clock``: MAVSDK runs on the sim clock (``native.attach``), so the port is a peer that lives on sim
    time (``LISTEN_HELLO``, settled like the script's MAVLink: MAVSDK binds it in this phase and the vehicle
    sends there from the next tick on). Otherwise the vehicle greets it on the wall clock until it answers
    (``LISTEN_HELLO_WALL``)."""
    sock = _original_socket(_socket.AF_INET, _socket.SOCK_DGRAM)
    try:
        sock.bind(("127.0.0.1", 0))
        sock.sendto(LISTEN_HELLO if sim_clock else LISTEN_HELLO_WALL, (ep.host, ep.udp_port))
        rt = INSTALLED.sockets
        if sim_clock and rt is not None:
            rt.mavlink_sent += 1
        return int(sock.getsockname()[1])
    finally:
        sock.close()
