"""A blocking connection to a channel, for any kind of peer (physics, autopilot, type 0, type 1, child).

Usage::

    with ChannelClient.connect("tcp://127.0.0.1:5760", PeerKind.AUTOPILOT, "autopilot-0",
                               vehicles=(0,)) as ch:
        while True:
            for msg in ch.recv():           # blocks until at least one message
                ...
            ch.send(EndTickAC(t_ns=..., vehicle=0, motors=(...)))

Thread safety: ``send`` may be called from several threads (a lock serialises writes); ``recv`` from
one thread at a time.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from types import TracebackType

from harness.core.errors import SimulationError
from harness.core.secrets import channel_secret
from harness.wire import protocol as p
from harness.wire.transport import Address, connect, parse_address


class ChannelClosed(SimulationError):
    """The channel closed the connection (end of run, or it dropped this peer)."""


class ChannelClient:
    def __init__(
        self,
        sock: socket.socket,
        welcome: p.Welcome,
        name: str,
        decoder: p.FrameDecoder | None = None,
        pending: list[p.Message] | None = None,
    ) -> None:
        self.sock = sock
        self.welcome = welcome
        self.name = name
        self._decoder = decoder or p.FrameDecoder()
        self._pending: list[p.Message] = pending or []
        self._wlock = threading.Lock()
        self.closed = False

    @classmethod
    def connect(
        cls,
        address: str | Address,
        kind: p.PeerKind,
        name: str,
        *,
        vehicle: int = -1,
        vehicles: tuple[int, ...] = (),
        secret: bytes | None = None,
        timeout_s: float = 10.0,
        answer_timeout_s: float = 60.0,
    ) -> ChannelClient:
        """Connect (within ``timeout_s``), answer the channel's challenge with our subscription, and wait for
        WELCOME. The channel's answers may take longer (``answer_timeout_s``): a run that starts a hundred
        processes on two busy cores answers their handshakes between starts, and one that gave up after
        10 s failed the whole run."""
        addr = parse_address(address) if isinstance(address, str) else address
        if secret is None:
            secret = channel_secret(None, None)  # $HARNESS_SECRET (or $HARNESS_CHANNEL_SECRET), inherited
        try:
            sock = connect(addr, timeout_s)
        except OSError as exc:
            raise SimulationError(f"cannot reach the channel at {addr}: {exc}") from None
        sock.settimeout(answer_timeout_s)
        dec = p.FrameDecoder()
        try:
            challenge, _ = _read_one(sock, dec, addr)
            if isinstance(challenge, p.Error):
                raise SimulationError(f"channel at {addr} refused the connection: {challenge.message}")
            if not isinstance(challenge, p.Challenge):
                raise SimulationError(f"channel at {addr} sent {type(challenge).__name__} instead of CHALLENGE")
            if challenge.version != p.PROTOCOL_VERSION:
                raise SimulationError(
                    f"channel at {addr} speaks protocol {challenge.version}, this harness {p.PROTOCOL_VERSION}"
                )
            auth = p.auth_token(secret, challenge.nonce, name) if secret else b""
            hello = p.Hello(p.PROTOCOL_VERSION, kind, name, vehicle, tuple(vehicles), auth)
            sock.sendall(p.encode(hello))
            reply, leftover = _read_one(sock, dec, addr)
        except (TimeoutError, OSError) as exc:
            sock.close()
            raise SimulationError(f"handshake with the channel at {addr} failed: {exc}") from None
        if isinstance(reply, p.Error):
            sock.close()
            raise SimulationError(f"channel at {addr} refused {name!r}: {reply.message}")
        if not isinstance(reply, p.Welcome):
            sock.close()
            raise SimulationError(f"channel at {addr} answered HELLO with {type(reply).__name__}")
        sock.settimeout(None)
        return cls(sock, reply, name, dec, leftover)

    def send(self, msg: p.Message) -> None:
        self.send_raw(p.encode(msg))

    def send_many(self, msgs: list[p.Message]) -> None:
        self.send_raw(p.encode_many(msgs))

    def send_raw(self, data: bytes) -> None:
        with self._wlock:
            try:
                self.sock.sendall(data)
            except OSError as exc:
                self.closed = True
                raise ChannelClosed(f"{self.name}: lost the channel while sending: {exc}") from None

    def recv(self) -> list[p.Message]:
        """Block until at least one message has arrived; return all that are complete."""
        if self._pending:
            out, self._pending = self._pending, []
            return out
        while True:
            try:
                data = self.sock.recv(262144)
            except OSError as exc:
                self.closed = True
                raise ChannelClosed(f"{self.name}: lost the channel: {exc}") from None
            if not data:
                self.closed = True
                raise ChannelClosed(f"{self.name}: the channel closed the connection")
            msgs = self._decoder.feed(data)
            if msgs:
                return msgs

    def recv_one(self) -> p.Message:
        msgs = self.recv()
        first, rest = msgs[0], msgs[1:]
        self._pending = rest + self._pending
        return first

    def hand_over(self) -> tuple[socket.socket, p.FrameDecoder, list[p.Message]]:
        """Give the connection to an event loop (a child channel's shell): the socket, the decoder with any
        partial frame in it, and the messages already decoded but not yet read. This client is done."""
        pending, self._pending = self._pending, []
        self.closed = True
        return self.sock, self._decoder, pending

    def close(self, reason: str = "", exit_code: int = 0) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            with self._wlock:
                self.sock.sendall(p.encode(p.Bye(reason, exit_code)))
        except OSError:
            pass
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()

    def __enter__(self) -> ChannelClient:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


def _read_one(sock: socket.socket, dec: p.FrameDecoder, addr: Address) -> tuple[p.Message, list[p.Message]]:
    while True:
        data = sock.recv(65536)
        if not data:
            raise SimulationError(f"channel at {addr} closed the connection during the handshake")
        msgs = dec.feed(data)
        if msgs:
            return msgs[0], msgs[1:]
