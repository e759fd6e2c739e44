"""The channel's I/O shell: sockets, the handshake, and the loop around the tick machine.

It accepts connections, runs the handshake (CHALLENGE, HELLO checked for version and shared secret, a small
frame limit until then), turns bytes into events of :class:`~harness.channel.machine.TickMachine` and its
actions into bytes, steps in-process autopilots when the machine says so, and asks the
:class:`~harness.channel.watchdog.Watchdog` how long it may block. Single-threaded over non-blocking
sockets (``selectors``). See docs/channel.md.
"""

from __future__ import annotations

import contextlib
import logging
import os
import selectors
import socket
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from harness.channel.config import ChannelConfig, Fault, MissionExit
from harness.channel.events import (
    Close,
    PeerLink,
    PeerState,
    Refused,
    RunFailed,
    Send,
    StepLocal,
    Stop,
    TickDone,
)
from harness.channel.machine import TickMachine
from harness.channel.watchdog import JOIN, Watchdog
from harness.core.clock import NS_PER_S, WALL, Clock, real_monotonic_ns, real_time_ns
from harness.core.errors import SimulationError
from harness.wire import protocol as p
from harness.wire.client import ChannelClient
from harness.wire.transport import Address, accept_tuned, connect, listen, parse_address

log = logging.getLogger(__name__)

LocalStep = Callable[[p.BeginTickAC], p.EndTickAC]


@dataclass(eq=False)
class _Connection:
    pid: int
    sock: socket.socket
    decoder: p.FrameDecoder
    name: str = "?"
    nonce: bytes = b""
    peer: PeerState | None = None
    """Set once the machine admitted it (or for the parent channel)."""
    out: bytearray = field(default_factory=bytearray)
    dirty: bool = False
    """Has output queued in ``out`` that the next flush sends."""
    want_write: bool = False
    """The socket was full: the selector watches it for writability."""
    send_error: str = ""
    """A send failed (the peer closed its end). What it sent before is still read (its BYE) before it is
    declared lost with this reason."""
    closed: bool = False


class Channel:
    """A lockstep channel. ``start()`` runs it in a thread; ``serve()`` runs it in the caller."""

    def __init__(self, config: ChannelConfig, clock: Clock | None = None) -> None:
        self.config = config
        self.trace: list[tuple[int, str, int, str]] = []
        self.failure: str | None = None
        self.address = ""
        self._clock: Clock = clock if clock is not None else WALL  # a test injects a ManualClock
        self._watchdog = Watchdog(self._clock)
        self.machine = TickMachine(
            self._watchdog,
            name=config.name,
            phase_every=config.phase_every,
            phase_period_ns=config.phase_period_ns,
            stall_timeout_s=config.stall_timeout_s,
            join_timeout_s=config.join_timeout_s,
            type1_fault=config.type1_fault,
            overlap_phase1=config.overlap_phase1,
            trace=self._record if config.trace else None,
        )
        self._epoch_ns = config.epoch_ns or real_time_ns()
        self._sel = selectors.DefaultSelector()
        self._conns: dict[int, _Connection] = {}
        self._next_pid = 1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server: socket.socket | None = None
        self._bound: Address | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._closed_all = False
        self._local_steps: dict[int, LocalStep] = {}
        self._dirty: list[_Connection] = []
        self._tick_result: tuple[p.EndTickAC, ...] | None = None

    # -- what the channel reports ------------------------------------------------------------------------

    @property
    def faults(self) -> list[Fault]:
        return self.machine.faults

    @property
    def mission_exits(self) -> list[MissionExit]:
        return self.machine.mission_exits

    @property
    def ticks_done(self) -> int:
        return self.machine.ticks_done

    def subscribers(self) -> list[tuple[str, str]]:
        """(name, kind) of every admitted peer below this channel (safe to call from another thread)."""
        return self.machine.subscribers()

    def held_vehicles(self) -> set[int]:
        """Vehicles whose autopilots (or child channels) have joined below this channel."""
        return self.machine.held_vehicles()

    def missions_below(self) -> int:
        """Missions of vehicles still running in the child channels below this one (as they announced)."""
        return self.machine.missions_below()

    def tree_size(self) -> int:
        """Admitted subscribers in the whole tree below this channel: its own, and what each child announced."""
        return self.machine.tree_size()

    def raise_if_failed(self) -> None:
        if self.failure:
            raise SimulationError(self.failure)

    # -- lifecycle -------------------------------------------------------------------------------------------

    def bind(self) -> str:
        if self._server is None:
            self._server, self._bound = listen(parse_address(self.config.address))
            self._server.setblocking(False)
            self._sel.register(self._server, selectors.EVENT_READ, None)
            self._wake_r.setblocking(False)
            self._sel.register(self._wake_r, selectors.EVENT_READ, None)
            self.address = str(self._bound)
            if self.config.parent:
                self._connect_parent(self.config.parent)
        return self.address

    def start(self) -> Channel:
        """Bind and run the loop in a daemon thread; ``address`` is valid on return."""
        self.bind()
        self._thread = threading.Thread(target=self.serve, name=f"channel-{self.config.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for the loop to end (physics left or the run failed); True if it ended."""
        if self._thread is None:
            return True
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def serve(self) -> None:
        """Run until stopped, physics leaves, or the run fails."""
        self.bind()
        try:
            while not self._stop.is_set():
                self._poll_once(self._watchdog.timeout_s())
        except RunFailed as exc:
            self._fail_run(str(exc))
        except Exception as exc:  # a bug must still end the run with a message, not hang it
            log.exception("channel %s crashed", self.config.name)
            self._fail_run(f"internal error in channel {self.config.name}: {exc!r}")
        finally:
            self._close_all()

    def close(self, reason: str = "end of run") -> None:
        """End the run for a local physics: tell every peer and close everything."""
        self._broadcast_bye(reason)
        self._close_all()

    # -- physics and autopilots in the same process ------------------------------------------------------------

    def attach_physics(self, name: str = "physics") -> None:
        """Make the calling thread the clock owner: it calls :meth:`step` once per tick.

        The root channel then lives inside the physics process (no socket hop between the two);
        every other participant still connects over real sockets.
        """
        if self.machine.up is not None or self.config.parent:
            raise SimulationError(f"channel {self.config.name} already has an upstream")
        self.bind()
        self.machine.attach_upstream(0, p.PeerKind.PHYSICS, name, PeerLink.IN_PROCESS)

    def attach_local_autopilots(self, vehicles: Iterable[int], step: LocalStep) -> None:
        """Autopilots in this process: ``step(BEGIN-TICK-AC) -> END-TICK-AC`` is called for their vehicles.

        They are one more peer of the tick machine (an in-process link): no socket hop per tick (the hop
        costs more than the autopilot itself); the phases for missions and network are unchanged.
        """
        vs = list(vehicles)
        for v in vs:
            self._local_steps[v] = step
        self.machine.attach_in_process(self._new_pid(), vs)

    def pump(self, timeout_s: float) -> None:
        """Between ticks: accept and admit joiners for up to ``timeout_s`` of wall time."""
        end = real_monotonic_ns() + int(timeout_s * NS_PER_S)
        try:
            while True:
                left = (end - real_monotonic_ns()) / NS_PER_S
                if left <= 0:
                    return
                self._poll_once(min(left, self._watchdog.timeout_s() or left))
        except RunFailed as exc:
            self._fail_run(str(exc))
            raise SimulationError(str(exc)) from None

    def wait_for(self, predicate: Callable[[list[tuple[str, str]]], bool], timeout_s: float) -> bool:
        """Pump until ``predicate(subscribers())`` holds; False after ``timeout_s``."""
        end = real_monotonic_ns() + int(timeout_s * NS_PER_S)
        while not predicate(self.subscribers()):
            if real_monotonic_ns() >= end:
                return False
            self.pump(0.01)
        return True

    def step(self, begin_ticks: list[p.BeginTickAC]) -> list[p.EndTickAC]:
        """One tick for a local physics: hand in its BEGIN-TICK-AC, get the END-TICK-AC back.

        Runs the channel loop in the calling thread until the tick (both phases) is complete.
        Raises :class:`SimulationError` when the run failed.
        """
        machine = self.machine
        up = machine.up
        if up is None or up.link is not PeerLink.IN_PROCESS:
            raise SimulationError("step() needs attach_physics() first")
        if self.failure:
            raise SimulationError(self.failure)
        self._tick_result = None
        try:
            if begin_ticks and begin_ticks[0].tick % self.config.phase_every == 0:
                # Read what came in between (WAKE of a mission left out by its lookahead, BYE, HELLO), and let
                # the phase 1 that ran beside physics end before this phase 0 begins.
                self._poll_once(0.0)
                while machine.phase1_running:
                    self._poll_once(self._watchdog.timeout_s())
            else:
                local = machine.local_only(begin_ticks)
                if local is not None:  # nothing but in-process autopilots this tick: no wait, no bookkeeping
                    steps = self._local_steps
                    etas = [steps[m.vehicle](m) for m in begin_ticks]
                    return machine.local_tick_done(begin_ticks, etas)
            for m in begin_ticks:
                machine.from_upstream(m)
            self._run_actions()
            while self._tick_result is None:
                self._poll_once(self._watchdog.timeout_s())
        except RunFailed as exc:
            self._fail_run(str(exc))
            raise SimulationError(str(exc)) from None
        result, self._tick_result = self._tick_result, None
        self._flush_dirty()
        return list(result)

    # -- the loop -----------------------------------------------------------------------------------------------

    def _poll_once(self, timeout: float | None) -> None:
        self._flush_dirty()
        for key, mask in self._sel.select(timeout):
            if key.fileobj is self._server:
                self._accept()
            elif key.fileobj is self._wake_r:
                with contextlib.suppress(OSError):
                    self._wake_r.recv(4096)
            else:
                conn: _Connection = key.data
                if mask & selectors.EVENT_WRITE:
                    self._flush(conn)
                if mask & selectors.EVENT_READ and not conn.closed:
                    self._read(conn)
        self._check_deadlines()

    def _run_actions(self) -> None:
        """Carry out what the machine asked for, in order (stepping in-process autopilots may ask for more)."""
        machine = self.machine
        while machine.actions:
            for action in machine.drain():
                if type(action) is Send:
                    conn = self._conns.get(action.peer.pid)
                    if conn is not None and not conn.closed and not conn.send_error:
                        conn.out += action.data
                        if not conn.dirty:
                            conn.dirty = True
                            self._dirty.append(conn)
                elif isinstance(action, StepLocal):
                    self._flush_dirty()  # remote BEGIN-TICK-AC go out before the in-process autopilots run
                    steps = self._local_steps
                    etas = [steps[m.vehicle](m) for m in action.begin_ticks]
                    machine.local_answers(action.peer, action.begin_ticks, etas)
                elif isinstance(action, Close):
                    conn = self._conns.get(action.peer.pid)
                    if conn is not None:
                        if action.error:
                            with contextlib.suppress(OSError):
                                conn.sock.send(action.error)
                        self._close_conn(conn)
                elif isinstance(action, TickDone):
                    self._tick_result = action.end_ticks
                elif isinstance(action, Stop):
                    self._broadcast_bye(action.reason)
                    self._stop.set()

    def _check_deadlines(self) -> None:
        expired = self._watchdog.expired()
        if not expired:
            return
        machine = self.machine
        for key in expired:
            if key == JOIN:
                machine.join_expired()
            conn = self._conns.get(key)
            if conn is None or conn.closed:
                self._watchdog.clear(key)
            elif conn.peer is None:
                limit = self.config.handshake_timeout_s
                self._handshake_failed(conn, f"stalled: no its HELLO within {limit:g} s", p.ErrorCode.STALLED)
            else:
                machine.expired(conn.peer)
            self._run_actions()

    # -- connections ----------------------------------------------------------------------------------------------

    def _new_pid(self) -> int:
        pid = self._next_pid
        self._next_pid += 1
        return pid

    def _add_conn(self, sock: socket.socket, decoder: p.FrameDecoder) -> _Connection:
        sock.setblocking(False)
        conn = _Connection(self._new_pid(), sock, decoder)
        self._conns[conn.pid] = conn
        self._sel.register(sock, selectors.EVENT_READ, conn)
        return conn

    def _accept(self) -> None:
        assert self._server is not None
        try:
            sock = accept_tuned(self._server)
        except OSError:
            return
        conn = self._add_conn(sock, p.FrameDecoder(max_frame=p.MAX_HELLO_BYTES))
        conn.nonce = os.urandom(16)
        self._watchdog.watch(conn.pid, self.config.handshake_timeout_s)
        self._queue(conn, p.encode(p.Challenge(p.PROTOCOL_VERSION, conn.nonce)))

    def _connect_parent(self, address: str) -> None:
        """As a child: subscribe to the parent channel with kind CHILD (blocking handshake)."""
        client = ChannelClient.connect(address, p.PeerKind.CHILD, self.config.name, secret=self.config.secret)
        welcome = client.welcome
        sock, decoder, pending = client.hand_over()
        conn = self._add_conn(sock, decoder)
        conn.name = "parent"
        conn.peer = self.machine.attach_upstream(conn.pid, p.PeerKind.CHILD, "parent")
        self._epoch_ns = welcome.epoch_ns
        self.machine.phase_period_ns = welcome.phase_period_ns
        for msg in pending:
            self.machine.from_upstream(msg)
        self._run_actions()

    def _queue(self, conn: _Connection, data: bytes) -> None:
        if conn.closed or conn.send_error:
            return
        conn.out += data
        if not conn.dirty:
            conn.dirty = True
            self._dirty.append(conn)

    def _flush_dirty(self) -> None:
        dirty = self._dirty
        if not dirty:
            return
        self._dirty = []
        for conn in dirty:
            conn.dirty = False
            if conn.out and not conn.want_write and not conn.closed:
                self._flush(conn)

    def _flush(self, conn: _Connection) -> None:
        try:
            n = conn.sock.send(conn.out)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            self._send_failed(conn, exc)
            return
        del conn.out[:n]
        if conn.out and not conn.want_write:
            conn.want_write = True
            self._sel.modify(conn.sock, selectors.EVENT_READ | selectors.EVENT_WRITE, conn)
        elif not conn.out and conn.want_write:
            conn.want_write = False
            self._sel.modify(conn.sock, selectors.EVENT_READ, conn)

    def _send_failed(self, conn: _Connection, exc: OSError) -> None:
        """The peer's end is gone. What it sent before (a mission's BYE with its exit code) may still wait
        unread: the selector reports the socket readable, ``_read`` takes that first, then the end of the
        stream declares the peer lost with this reason."""
        why = f"connection broke while sending: {exc}"
        if conn.peer is not None and conn.peer.upstream:
            self._lost(conn, why)
            return
        conn.send_error = why
        conn.out.clear()
        if conn.want_write:
            conn.want_write = False
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._sel.modify(conn.sock, selectors.EVENT_READ, conn)

    def _lost(self, conn: _Connection, why: str) -> None:
        if conn.peer is None:
            self._handshake_failed(conn, why, p.ErrorCode.PEER_LOST)
        else:
            self.machine.lost(conn.peer, why)
        self._run_actions()

    def _read(self, conn: _Connection) -> None:
        try:
            data = conn.sock.recv(262144)
        except BlockingIOError:
            return
        except OSError as exc:
            self._lost(conn, f"connection broke: {exc}")
            return
        if not data:
            self._lost(conn, conn.send_error or "disconnected")
            return
        machine = self.machine
        try:
            msgs = conn.decoder.feed(data)
        except p.ProtocolError as exc:
            if conn.peer is None:
                self._handshake_failed(conn, f"sent a malformed frame before its HELLO ({exc})", p.ErrorCode.MALFORMED)
            else:
                machine.malformed(conn.peer, str(exc))
                self._run_actions()
            return
        for msg in msgs:
            peer = conn.peer
            if conn.closed or (peer is not None and peer.closed):
                break  # dropped by an earlier message of this read
            if peer is None:
                self._on_hello(conn, msg)
            elif peer.upstream:
                machine.from_upstream(msg)
            else:
                machine.receive(peer, msg)
        self._run_actions()

    # -- handshake and admission ------------------------------------------------------------------------------------

    def _on_hello(self, conn: _Connection, msg: p.Message) -> None:
        if not isinstance(msg, p.Hello):
            self._reject(conn, p.ErrorCode.UNEXPECTED, f"expected HELLO, got {type(msg).__name__}")
            return
        conn.name = msg.name
        if msg.version != p.PROTOCOL_VERSION:
            self._reject(
                conn, p.ErrorCode.BAD_VERSION, f"protocol {msg.version} offered, channel speaks {p.PROTOCOL_VERSION}"
            )
            return
        if self.config.secret and not p.check_auth(self.config.secret, conn.nonce, msg.name, msg.auth):
            self._reject(conn, p.ErrorCode.BAD_AUTH, f"{msg.name!r} did not prove the shared secret")
            return
        if msg.kind == p.PeerKind.PHYSICS and self.config.parent:
            self._reject(conn, p.ErrorCode.UNEXPECTED, "this channel already has a clock owner")
            return
        self._watchdog.clear(conn.pid)
        try:
            peer = self.machine.join(conn.pid, msg)
        except Refused as exc:
            self._reject(conn, exc.code, str(exc))
            return
        conn.peer = peer
        conn.decoder.max_frame = p.MAX_FRAME_BYTES  # admitted: the full frame size from now on
        # queued ahead of what the admission asked for it (a BEGIN-TICK-0 of the phase it joined)
        self._queue(conn, p.encode(p.Welcome(conn.pid, self._epoch_ns, self.machine.phase_period_ns)))

    def _reject(self, conn: _Connection, code: p.ErrorCode, why: str) -> None:
        log.warning("channel %s: refused %r: %s", self.config.name, conn.name, why)
        self._queue(conn, p.encode(p.Error(code, why, fatal=True)))
        self._close_conn(conn)

    def _handshake_failed(self, conn: _Connection, why: str, code: p.ErrorCode) -> None:
        """A connection that never became a peer: noted as a fault of kind HANDSHAKE, never fatal."""
        log.warning("channel %s: dropped a connection before its subscription: %s", self.config.name, why)
        self.machine.faults.append(Fault(conn.name, "HANDSHAKE", -1, why, self.machine.tick, False))
        with contextlib.suppress(OSError):
            conn.sock.send(p.encode(p.Error(code, f"peer {conn.name!r} {why}", fatal=True)))
        self._close_conn(conn)

    # -- closing ----------------------------------------------------------------------------------------------------

    def _close_conn(self, conn: _Connection) -> None:
        if conn.closed:
            return
        if conn.out and not conn.send_error:
            with contextlib.suppress(OSError):  # best effort: what was queued for it (an ERROR saying why)
                conn.sock.send(conn.out)
        conn.out.clear()
        conn.closed = True
        self._watchdog.clear(conn.pid)
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(conn.sock)
        with contextlib.suppress(OSError):
            conn.sock.close()
        self._conns.pop(conn.pid, None)

    def _broadcast_bye(self, reason: str) -> None:
        self._flush_dirty()
        data = p.encode(p.Bye(reason))
        for conn in list(self._conns.values()):
            if conn.peer is None or not conn.peer.upstream:
                with contextlib.suppress(OSError):
                    conn.sock.send(data)

    def _fail_run(self, message: str) -> None:
        self._flush_dirty()
        self.failure = message
        log.info("channel %s: run failed: %s", self.config.name, message)  # whoever runs the channel reports it
        data = p.encode(p.Error(p.ErrorCode.PEER_LOST, message, fatal=True))
        for conn in list(self._conns.values()):
            with contextlib.suppress(OSError):
                conn.sock.send(data)

    def _close_all(self) -> None:
        if self._closed_all:
            return
        self._closed_all = True
        for conn in list(self._conns.values()):
            self._close_conn(conn)
        for s in (self._server, self._wake_r, self._wake_w):
            if s is not None:
                with contextlib.suppress(OSError):
                    s.close()
        self._sel.close()
        if self._bound is not None and self._bound.scheme == "unix" and not self._bound.is_abstract:
            with contextlib.suppress(OSError):
                os.unlink(self._bound.path)

    def _record(self, event: str, tick: int, peer: str) -> None:
        self.trace.append((self._clock.now_ns(), event, tick, peer))


def connect_child_socket(address: str) -> socket.socket:
    """Open a raw connection to a channel (tests of malformed input)."""
    return connect(parse_address(address))
