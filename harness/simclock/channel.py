"""The channel (the paper's GZUAVCHANNEL): keeps physics, autopilots, missions and network in lockstep.

One tick, as DESIGN.md "The tick" describes it:

1. physics sends BEGIN-TICK-AC for every vehicle (``count`` of them);
2. the channel forwards each to the autopilot (or child channel) holding that vehicle and, if this tick
   runs the phases, sends BEGIN-TICK-0 to every type-0 subscriber and child channel;
3. phase 0: autopilots answer END-TICK-AC, type-0 subscribers ENQUEUE packets and answer END-TICK-0;
4. when all of phase 0 is in, phase 1: BEGIN-TICK-1 (positions of this tick, packets of this phase 0)
   to every type-1 subscriber and child; they DELIVER packets and answer END-TICK-1;
5. only then do the END-TICK-AC go back to physics.

A channel whose upstream is another channel (``ChannelConfig.parent``) is a *child*: it obeys the
BEGIN-TICK-0/1 of its parent instead of deciding the phases, and answers for its whole subtree, so the
two phases stay strictly separated across the whole tree.

The loop is single-threaded over non-blocking sockets (``selectors``); a wall-clock watchdog guards
every wait on a peer. Faults are reported by peer name: a type-0 subscriber that dies, stalls or sends
garbage is dropped and its mission reported failed; a type-1 subscriber's fault fails the run (or drops
it, by configuration); an autopilot's or child's fault fails the run.
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
from typing import Literal

from harness.core.clock import NS_PER_S, real_monotonic_ns, real_time_ns
from harness.core.errors import ScenarioError, SimulationError
from harness.simclock import protocol as p
from harness.simclock.transport import Address, accept_tuned, connect, listen, parse_address

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ChannelConfig:
    address: str = "tcp://127.0.0.1:0"
    """Where to listen. Anything but loopback (or a unix socket) requires ``secret``."""
    name: str = "channel"
    parent: str | None = None
    """Address of the parent channel: this channel is then a child in a tree."""
    secret: bytes | None = None
    """Shared secret every peer must prove (HMAC of a nonce); required off loopback."""
    tick_hz: float = 250.0
    phase_every: int = 1
    """Phases 0 and 1 run on every tick whose index is a multiple of this (root only)."""
    stall_timeout_s: float = 10.0
    """Wall-clock limit on every wait for a subscriber's answer."""
    join_timeout_s: float = 30.0
    """Wall-clock limit on waiting for an autopilot of a vehicle that physics simulates."""
    handshake_timeout_s: float = 10.0
    type1_fault: Literal["fail", "drop"] = "fail"
    epoch_ns: int = 0
    """Unix time of sim time zero, told to every peer; 0 means the wall time at start."""
    trace: bool = False
    """Record (wall ns, event, tick, peer) for every phase transition (tests, debugging)."""
    overlap_phase1: bool = True
    """Root only. True: END-TICK-AC go back to physics as soon as phase 0 and the autopilots are done, and
    phase 1 (the network simulating the interval with the positions of its tick) runs while physics
    integrates the next ticks; the next phase 0 starts only when every END-TICK-1 is in. Nothing inside the
    simulation can tell the difference: missions are not running then, and the network saw only its
    tick's positions. False: the paper's strict order (physics waits for every END-TICK-1), which is also what
    happens while a child channel takes part in the phase."""

    def __post_init__(self) -> None:
        if self.tick_hz <= 0:
            raise ScenarioError(f"channel: tick_hz must be > 0, got {self.tick_hz}")
        if self.phase_every < 1:
            raise ScenarioError(f"channel: phase_every must be a positive integer, got {self.phase_every}")
        if self.stall_timeout_s <= 0:
            raise ScenarioError(f"channel: stall_timeout_s must be > 0, got {self.stall_timeout_s}")
        if not parse_address(self.address).is_loopback and not self.secret:
            raise ScenarioError(
                f"channel {self.name}: listening on {self.address} (not loopback) requires a shared secret"
            )

    @property
    def phase_period_ns(self) -> int:
        return round(self.phase_every * NS_PER_S / self.tick_hz)


@dataclass(frozen=True)
class Fault:
    """A peer that was dropped or failed the run."""

    peer: str
    kind: str
    vehicle: int
    reason: str
    tick: int
    fatal: bool


@dataclass
class MissionExit:
    peer: str
    vehicle: int
    exit_code: int
    reason: str


@dataclass(eq=False)
class _Peer:
    pid: int
    sock: socket.socket
    name: str = "?"
    kind: p.PeerKind | None = None
    vehicle: int = -1
    vehicles: set[int] = field(default_factory=set)
    mission_vehicles: set[int] = field(default_factory=set)
    members: int = 0  # a child channel's admitted subscribers (its own Announce)
    decoder: p.FrameDecoder = field(default_factory=p.FrameDecoder)
    out: bytearray = field(default_factory=bytearray)
    nonce: bytes = b""
    admitted: bool = False
    upstream: bool = False
    deadline_ns: int | None = None
    waiting_for: str = ""
    closed: bool = False
    dirty: bool = False
    """Has output queued in ``out`` that the next flush sends."""
    want_write: bool = False
    """The socket was full: the selector watches it for writability."""
    send_error: str = ""
    """A send failed (the peer closed its end). What it sent before is still read (its BYE) before it is
    declared lost with this reason."""
    idle_until_ns: int = p.EVERY_PHASE
    """Lookahead from its last END-TICK-0/1: leave it out of its phase before this sim time."""
    deliver_wakes: bool = True
    woken: bool = False
    """A WAKE (type 0) arrived: include it in the next phase 0."""
    delivered: bool = False
    """A DELIVER was routed to it (type 0) since its last phase 0."""

    @property
    def label(self) -> str:
        kind = self.kind.name if self.kind is not None else "peer"
        return f"{kind} {self.name!r}"


class _Fatal(Exception):
    pass


class Channel:
    """A lockstep channel. ``start()`` runs it in a thread; ``serve()`` runs it in the caller."""

    def __init__(self, config: ChannelConfig) -> None:
        self.config = config
        self.faults: list[Fault] = []
        self.mission_exits: list[MissionExit] = []
        self.trace: list[tuple[int, str, int, str]] = []
        self.failure: str | None = None
        self.ticks_done = 0
        self.address = ""
        self._epoch_ns = config.epoch_ns or real_time_ns()
        self._phase_period_ns = config.phase_period_ns
        self._sel = selectors.DefaultSelector()
        self._peers: dict[int, _Peer] = {}
        self._next_pid = 1
        self._up: _Peer | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server: socket.socket | None = None
        self._bound: Address | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        # tick state
        self._in_tick = False
        self._t_ns = -1
        self._tick = -1
        self._bta: list[p.BeginTickAC] = []
        self._bta_count = 0
        self._routed = False
        self._etas: dict[int, p.EndTickAC] = {}
        self._phase_tick = False
        self._phase0_started = False
        self._phase0_done = False
        self._phase1_started = False
        self._p1_t_ns = -1
        """Sim time of the last phase 1 started (it may still run while physics goes on: ``overlap_phase1``)."""
        self._wait0: set[_Peer] = set()
        self._wait1: set[_Peer] = set()
        self._wait_ac: dict[_Peer, set[int]] = {}
        self._packets: list[p.Packet] = []
        self._positions: dict[int, p.Vec3] = {}
        self._join_deadline: int | None = None
        self._etas_sent_up = False
        self._local = False
        self._closed_all = False
        self._deadlines: dict[_Peer, int] = {}
        self._local_autopilots: dict[int, Callable[[p.BeginTickAC], p.EndTickAC]] = {}
        self._members: dict[p.PeerKind, list[_Peer]] | None = None
        self._routes: dict[int, list[_Peer]] | None = None
        self._holders: dict[int, _Peer] | None = None
        self._unadmitted = 0
        self._dirty: list[_Peer] = []
        self._tick_result: list[p.EndTickAC] | None = None

    # -- lifecycle ----------------------------------------------------------------------------

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
                self._poll_once(self._next_timeout())
        except _Fatal as exc:
            self._fail_run(str(exc))
        except Exception as exc:  # a bug must still end the run with a message, not hang it
            log.exception("channel %s crashed", self.config.name)
            self._fail_run(f"internal error in channel {self.config.name}: {exc!r}")
        finally:
            self._close_all()

    def _poll_once(self, timeout: float | None) -> None:
        self._flush_dirty()
        for key, mask in self._sel.select(timeout):
            if key.fileobj is self._server:
                self._accept()
            elif key.fileobj is self._wake_r:
                with contextlib.suppress(OSError):
                    self._wake_r.recv(4096)
            else:
                peer: _Peer = key.data
                if mask & selectors.EVENT_WRITE:
                    self._flush(peer)
                if mask & selectors.EVENT_READ and not peer.closed:
                    self._read(peer)
        self._check_deadlines()

    # -- physics in the same process ------------------------------------------------------------

    def attach_physics(self, name: str = "physics") -> None:
        """Make the calling thread the clock owner: it calls :meth:`step` once per tick.

        The root channel then lives inside the physics process (no socket hop between the two);
        every other participant still connects over real sockets.
        """
        if self._up is not None or self.config.parent:
            raise SimulationError(f"channel {self.config.name} already has an upstream")
        self.bind()
        a, b = socket.socketpair()  # a placeholder socket: the local upstream never reads or writes
        self._local_pair = (a, b)
        self._up = _Peer(0, a, name=name, kind=p.PeerKind.PHYSICS, upstream=True, admitted=True)
        self._local = True

    def attach_local_autopilots(self, vehicles: Iterable[int], step: Callable[[p.BeginTickAC], p.EndTickAC]) -> None:
        """Autopilots in this process: ``step(BEGIN-TICK-AC) -> END-TICK-AC`` is called for their vehicles.

        No socket hop per tick (the hop costs more than the autopilot itself); the phases for missions
        and network are unchanged.
        """
        for v in vehicles:
            self._local_autopilots[v] = step

    def pump(self, timeout_s: float) -> None:
        """Between ticks: accept and admit joiners for up to ``timeout_s`` of wall time."""
        end = real_monotonic_ns() + int(timeout_s * NS_PER_S)
        try:
            while True:
                left = (end - real_monotonic_ns()) / NS_PER_S
                if left <= 0:
                    return
                self._poll_once(min(left, self._next_timeout() or left))
        except _Fatal as exc:
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
        if not self._local:
            raise SimulationError("step() needs attach_physics() first")
        if self.failure:
            raise SimulationError(self.failure)
        self._tick_result = None
        try:
            if begin_ticks and begin_ticks[0].tick % self.config.phase_every == 0:
                # A tick whose autopilots are all in this process completes without waiting for a socket;
                # read what came in between (WAKE of a mission left out by its lookahead, BYE, HELLO), and
                # let the phase 1 that ran beside physics end before this phase 0 begins.
                self._poll_once(0.0)
                while self._wait1:
                    self._poll_once(self._next_timeout())
            elif self._local_only(begin_ticks):
                return self._local_tick(begin_ticks)
            for m in begin_ticks:
                self._on_upstream(m)
            while self._tick_result is None:
                self._poll_once(self._next_timeout())
        except _Fatal as exc:
            self._fail_run(str(exc))
            raise SimulationError(str(exc)) from None
        result, self._tick_result = self._tick_result, None
        self._flush_dirty()
        return result

    def _local_only(self, begin_ticks: list[p.BeginTickAC]) -> bool:
        """A tick without phases whose vehicles all fly on in-process autopilots: nothing to wait for."""
        local = self._local_autopilots
        return bool(begin_ticks) and not self._in_tick and all(m.vehicle in local for m in begin_ticks)

    def _local_tick(self, begin_ticks: list[p.BeginTickAC]) -> list[p.EndTickAC]:
        """The same tick as the general path (BEGIN-TICK-AC to the autopilots, END-TICK-AC back), without
        the bookkeeping that only subscribers and remote peers need: 4 ticks out of 5 in ``harness run``."""
        first = begin_ticks[0]
        if first.t_ns < self._t_ns:
            raise _Fatal(f"upstream went back in time ({first.t_ns} ns < {self._t_ns} ns)")
        self._t_ns, self._tick = first.t_ns, first.tick
        etas = sorted((self._step_local(m) for m in begin_ticks), key=_by_vehicle)
        self._trace("eta_up", None)
        self.ticks_done += 1
        return etas

    def close(self, reason: str = "end of run") -> None:
        """End the run for a local physics: tell every peer and close everything."""
        self._broadcast_bye(reason)
        self._close_all()
        for s in getattr(self, "_local_pair", ()):
            with contextlib.suppress(OSError):
                s.close()

    # -- connections --------------------------------------------------------------------------

    def _add_peer(self, sock: socket.socket) -> _Peer:
        sock.setblocking(False)
        peer = _Peer(self._next_pid, sock)
        self._next_pid += 1
        self._peers[peer.pid] = peer
        self._sel.register(sock, selectors.EVENT_READ, peer)
        return peer

    def _accept(self) -> None:
        assert self._server is not None
        try:
            sock = accept_tuned(self._server)
        except OSError:
            return
        peer = self._add_peer(sock)
        peer.nonce = os.urandom(16)
        self._set_deadline(peer, real_monotonic_ns() + int(self.config.handshake_timeout_s * NS_PER_S))
        peer.waiting_for = "its HELLO"
        self._send(peer, p.Challenge(p.PROTOCOL_VERSION, peer.nonce))

    def _connect_parent(self, address: str) -> None:
        """As a child: subscribe to the parent channel with kind CHILD (blocking handshake)."""
        from harness.simclock.client import ChannelClient

        client = ChannelClient.connect(address, p.PeerKind.CHILD, self.config.name, secret=self.config.secret)
        sock = client.sock
        up = self._add_peer(sock)
        up.name, up.kind, up.upstream, up.admitted = "parent", p.PeerKind.CHILD, True, True
        up.decoder = client._decoder
        self._up = up
        self._epoch_ns = client.welcome.epoch_ns
        self._phase_period_ns = client.welcome.phase_period_ns
        for msg in client._pending:
            self._on_upstream(msg)

    def _send(self, peer: _Peer, msg: p.Message) -> None:
        self._send_raw(peer, p.encode(msg))

    def _send_raw(self, peer: _Peer, data: bytes) -> None:
        """Queue ``data`` for ``peer``; it goes out with everything else queued for it at the next flush
        (before the channel blocks again), so a burst of messages costs one system call per peer."""
        if peer.closed or peer.send_error:
            return
        peer.out += data
        if not peer.dirty:
            peer.dirty = True
            self._dirty.append(peer)

    def _flush_dirty(self) -> None:
        dirty = self._dirty
        if not dirty:
            return
        self._dirty = []
        for peer in dirty:
            peer.dirty = False
            if peer.out and not peer.want_write and not peer.closed:
                self._flush(peer)

    def _flush(self, peer: _Peer) -> None:
        try:
            n = peer.sock.send(peer.out)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            self._send_failed(peer, exc)
            return
        del peer.out[:n]
        if peer.out and not peer.want_write:
            peer.want_write = True
            self._sel.modify(peer.sock, selectors.EVENT_READ | selectors.EVENT_WRITE, peer)
        elif not peer.out and peer.want_write:
            peer.want_write = False
            self._sel.modify(peer.sock, selectors.EVENT_READ, peer)

    def _send_failed(self, peer: _Peer, exc: OSError) -> None:
        """The peer's end is gone. What it sent before (a mission's BYE with its exit code) may still wait
        unread: the selector reports the socket readable, ``_read`` takes that first, then the end of the
        stream declares the peer lost with this reason."""
        why = f"connection broke while sending: {exc}"
        if peer.upstream:
            self._peer_lost(peer, why)
            return
        peer.send_error = why
        peer.out.clear()
        if peer.want_write:
            peer.want_write = False
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._sel.modify(peer.sock, selectors.EVENT_READ, peer)

    def _read(self, peer: _Peer) -> None:
        try:
            data = peer.sock.recv(262144)
        except BlockingIOError:
            return
        except OSError as exc:
            self._peer_lost(peer, f"connection broke: {exc}")
            return
        if not data:
            self._peer_lost(peer, peer.send_error or "disconnected")
            return
        try:
            msgs = peer.decoder.feed(data)
        except p.ProtocolError as exc:
            self._peer_fault(peer, f"sent a malformed frame ({exc})", p.ErrorCode.MALFORMED)
            return
        for msg in msgs:
            if peer.closed:
                return
            if peer.upstream:
                self._on_upstream(msg)
            elif peer.kind is None:
                self._on_hello(peer, msg)
            else:
                self._on_message(peer, msg)

    # -- handshake and admission --------------------------------------------------------------

    def _on_hello(self, peer: _Peer, msg: p.Message) -> None:
        if not isinstance(msg, p.Hello):
            self._reject(peer, p.ErrorCode.UNEXPECTED, f"expected HELLO, got {type(msg).__name__}")
            return
        peer.name = msg.name
        if msg.version != p.PROTOCOL_VERSION:
            self._reject(
                peer, p.ErrorCode.BAD_VERSION, f"protocol {msg.version} offered, channel speaks {p.PROTOCOL_VERSION}"
            )
            return
        if self.config.secret and not p.check_auth(self.config.secret, peer.nonce, msg.name, msg.auth):
            self._reject(peer, p.ErrorCode.BAD_AUTH, f"{msg.name!r} did not prove the shared secret")
            return
        kind = p.PeerKind(msg.kind)
        if kind == p.PeerKind.PHYSICS and (self._up is not None or self.config.parent):
            self._reject(peer, p.ErrorCode.UNEXPECTED, "this channel already has a clock owner")
            return
        if kind == p.PeerKind.AUTOPILOT:
            if not msg.vehicles:
                self._reject(peer, p.ErrorCode.UNEXPECTED, "an autopilot must hold at least one vehicle")
                return
            taken = set(msg.vehicles) & self._held_vehicles()
            if taken:
                self._reject(peer, p.ErrorCode.UNEXPECTED, f"vehicles {sorted(taken)} already have an autopilot")
                return
        peer.kind = kind
        peer.vehicle = msg.vehicle
        peer.vehicles = set(msg.vehicles)
        self._set_deadline(peer, None)
        self._send(peer, p.Welcome(peer.pid, self._epoch_ns, self._phase_period_ns))
        log.info("channel %s: %s joined (vehicles %s)", self.config.name, peer.label, sorted(peer.vehicles))
        if kind == p.PeerKind.PHYSICS:
            peer.upstream = peer.admitted = True
            self._up = peer
        elif not self._in_tick or self._join_deadline is not None:
            self._admit(peer)
            self._progress()
        else:
            self._unadmitted += 1  # joins between two ticks

    def _reject(self, peer: _Peer, code: p.ErrorCode, why: str) -> None:
        log.warning("channel %s: refused %r: %s", self.config.name, peer.name, why)
        self._send(peer, p.Error(code, why, fatal=True))
        self._close_peer(peer)

    def _held_vehicles(self) -> set[int]:
        held: set[int] = set()
        for peer in self._peers.values():
            if peer.kind in (p.PeerKind.AUTOPILOT, p.PeerKind.CHILD) and not peer.upstream and not peer.closed:
                held |= peer.vehicles
        return held

    def _admit(self, peer: _Peer) -> None:
        peer.admitted = True
        self._membership_changed()
        self._announce_up()

    def _admit_pending(self) -> None:
        if not self._unadmitted:
            return
        self._unadmitted = 0
        for peer in list(self._peers.values()):
            if peer.kind is not None and not peer.admitted and not peer.closed:
                self._admit(peer)

    def _membership_changed(self) -> None:
        self._members = self._routes = self._holders = None

    def _announce_up(self) -> None:
        if self._up is None or self._up.kind != p.PeerKind.CHILD:
            return
        held, missions = set(), set()
        for peer in self._active():
            if peer.kind in (p.PeerKind.AUTOPILOT, p.PeerKind.CHILD):
                held |= peer.vehicles
            if peer.kind == p.PeerKind.TYPE0 and peer.vehicle >= 0:
                missions.add(peer.vehicle)
            if peer.kind == p.PeerKind.CHILD:
                missions |= peer.mission_vehicles
        self._send(self._up, p.Announce(tuple(sorted(held)), tuple(sorted(missions)), self.tree_size()))

    def _active(self, *kinds: p.PeerKind) -> Iterable[_Peer]:
        """Admitted peers below this channel, of ``kinds`` (all kinds if none); cached per membership."""
        members = self._members
        if members is None:
            members = {}
            for peer in self._peers.values():
                if peer.admitted and not peer.upstream and not peer.closed and peer.kind is not None:
                    members.setdefault(peer.kind, []).append(peer)
            self._members = members
        if not kinds:
            return [peer for group in members.values() for peer in group]
        if len(kinds) == 1:
            return members.get(kinds[0], ())
        return [peer for kind in kinds for peer in members.get(kind, ())]

    # -- messages from below ------------------------------------------------------------------

    def _on_message(self, peer: _Peer, msg: p.Message) -> None:
        if isinstance(msg, p.EndTickAC):
            self._on_end_tick_ac(peer, msg)
        elif isinstance(msg, p.EndTick0):
            peer.idle_until_ns, peer.deliver_wakes = msg.idle_until_ns, msg.deliver_wakes
            self._on_phase_end(peer, msg.t_ns, self._wait0, "0")
        elif isinstance(msg, p.EndTick1):
            peer.idle_until_ns = msg.idle_until_ns
            self._on_phase_end(peer, msg.t_ns, self._wait1, "1")
        elif isinstance(msg, p.Wake):
            peer.woken = True
        elif isinstance(msg, p.Enqueue):
            self._on_enqueue(peer, msg)
        elif isinstance(msg, p.Deliver | p.DeliverMany):
            self._route_deliver(msg, source=peer)
        elif isinstance(msg, p.Announce):
            peer.vehicles = set(msg.vehicles)
            peer.mission_vehicles = set(msg.mission_vehicles)
            peer.members = msg.members
            self._membership_changed()
            self._announce_up()
            self._progress()
        elif isinstance(msg, p.Bye):
            self._on_bye(peer, msg)
        elif isinstance(msg, p.Error):
            self._peer_fault(peer, f"reported an error: {msg.message}", p.ErrorCode.PEER_LOST)
        else:
            self._peer_fault(peer, f"sent {type(msg).__name__}, which it may not send", p.ErrorCode.UNEXPECTED)

    def _on_phase_end(self, peer: _Peer, t_ns: int, waiting: set[_Peer], phase: str) -> None:
        """END-TICK-0 / END-TICK-1: ``peer`` is done with this tick's phase (and only then may say so)."""
        if peer not in waiting or t_ns != (self._p1_t_ns if phase == "1" else self._t_ns):
            self._peer_fault(peer, f"sent END-TICK-{phase} for t={t_ns} ns out of phase", p.ErrorCode.UNEXPECTED)
            return
        waiting.discard(peer)
        self._set_deadline(peer, None)
        self._trace(f"et{phase}", peer)
        self._progress()

    def _on_end_tick_ac(self, peer: _Peer, msg: p.EndTickAC) -> None:
        waiting = self._wait_ac.get(peer)
        if msg.t_ns != self._t_ns or waiting is None or msg.vehicle not in waiting:
            self._peer_fault(
                peer, f"sent END-TICK-AC for vehicle {msg.vehicle} at t={msg.t_ns} ns unasked", p.ErrorCode.UNEXPECTED
            )
            return
        waiting.discard(msg.vehicle)
        self._etas[msg.vehicle] = msg
        if not waiting:
            del self._wait_ac[peer]
            self._set_deadline(peer, None)
        self._progress()

    def _on_enqueue(self, peer: _Peer, msg: p.Enqueue) -> None:
        if peer not in self._wait0:
            self._peer_fault(peer, "sent ENQUEUE outside its phase 0", p.ErrorCode.UNEXPECTED)
            return
        if self._up is not None and self._up.kind == p.PeerKind.CHILD:
            self._send(self._up, msg)  # the root collects every packet of the tree
        else:
            self._packets.append(msg.packet)

    def _on_bye(self, peer: _Peer, msg: p.Bye) -> None:
        if peer.kind == p.PeerKind.TYPE0:
            self.mission_exits.append(MissionExit(peer.name, peer.vehicle, msg.exit_code, msg.reason))
            log.info("channel %s: %s left (exit %d) %s", self.config.name, peer.label, msg.exit_code, msg.reason)
            self._close_peer(peer)
            self._announce_up()
            self._progress()
        elif peer.kind == p.PeerKind.TYPE1 and peer not in self._wait1:
            self._close_peer(peer)
        else:
            self._peer_fault(peer, f"left the run ({msg.reason or 'no reason given'})", p.ErrorCode.PEER_LOST)

    def _route_deliver(self, msg: p.Deliver | p.DeliverMany, source: _Peer | None) -> None:
        dst = msg.dst if isinstance(msg, p.DeliverMany) else msg.packet.dst
        routes = self._routes
        if routes is None:
            routes = {}
            for peer in self._active(p.PeerKind.TYPE0):
                routes.setdefault(peer.vehicle, []).append(peer)
            self._routes = routes
        for peer in routes.get(dst, ()):
            peer.delivered = True
            self._send(peer, msg)
        for peer in self._active(p.PeerKind.CHILD):
            if peer is not source and dst in peer.mission_vehicles:
                self._send(peer, msg)
        if self._up is not None and self._up.kind == p.PeerKind.CHILD and source is not self._up:
            self._send(self._up, msg)

    # -- messages from above ------------------------------------------------------------------

    def _on_upstream(self, msg: p.Message) -> None:
        if isinstance(msg, p.BeginTickAC):
            if not self._in_tick:
                self._begin_tick(msg.t_ns, msg.tick)
            elif msg.t_ns != self._t_ns or self._routed:
                raise _Fatal(f"upstream sent BEGIN-TICK-AC for t={msg.t_ns} ns while tick t={self._t_ns} ns runs")
            self._bta.append(msg)
            self._bta_count = msg.count
            self._positions[msg.vehicle] = msg.position_ned_m
            if len(self._bta) >= self._bta_count:
                self._route_ticks()
        elif isinstance(msg, p.BeginTick0):  # child: the parent runs phase 0 now
            if not self._in_tick:
                self._begin_tick(msg.t_ns, msg.tick)
            self._phase_tick = True
            self._start_phase0()
        elif isinstance(msg, p.BeginTick1):
            self._start_phase1(msg)
        elif isinstance(msg, p.Deliver | p.DeliverMany):
            self._route_deliver(msg, source=self._up)
        elif isinstance(msg, p.Bye):
            log.info("channel %s: upstream left (%s)", self.config.name, msg.reason or "end of run")
            self._broadcast_bye(msg.reason or "end of run")
            self._stop.set()
        elif isinstance(msg, p.Error):
            raise _Fatal(f"upstream reported: {msg.message}")
        elif isinstance(msg, p.Welcome | p.Challenge):
            pass
        else:
            raise _Fatal(f"upstream sent {type(msg).__name__}, which it may not send")
        self._progress()

    def _begin_tick(self, t_ns: int, tick: int) -> None:
        if t_ns < self._t_ns:
            raise _Fatal(f"upstream went back in time ({t_ns} ns < {self._t_ns} ns)")
        self._admit_pending()
        self._in_tick = True
        self._t_ns, self._tick = t_ns, tick
        self._bta, self._bta_count, self._routed = [], 0, False
        self._etas = {}
        self._packets, self._positions = [], {}
        self._phase0_started = self._phase0_done = self._phase1_started = False
        self._etas_sent_up = False
        is_root = self._up is not None and self._up.kind == p.PeerKind.PHYSICS
        self._phase_tick = is_root and tick % self.config.phase_every == 0
        if self._phase0_may_start():
            self._start_phase0()  # else when the phase 1 still running ends, or the local autopilots have run

    def _phase0_may_start(self) -> bool:
        """Phase 0 starts once the previous phase 1 is over and, with in-process autopilots, after they have
        stepped this tick: what they send their missions over MAVLink at this tick is then in the missions'
        sockets before phase 0 begins, so a script reads it in this phase whatever the machine's pace."""
        return self._phase_tick and not self._wait1 and (self._routed or not self._local_autopilots)

    def _route_ticks(self) -> None:
        """Forward this tick's BEGIN-TICK-AC to the holders of the vehicles, with per-holder counts."""
        holders = self._holders
        if holders is None:
            holders = {}
            for peer in self._active(p.PeerKind.AUTOPILOT, p.PeerKind.CHILD):
                for v in peer.vehicles:
                    holders[v] = peer
            self._holders = holders
        local = self._local_autopilots
        missing = sorted({m.vehicle for m in self._bta} - holders.keys() - local.keys())
        if missing:
            if self._join_deadline is None:
                self._join_deadline = real_monotonic_ns() + int(self.config.join_timeout_s * NS_PER_S)
                log.info("channel %s: waiting for autopilots of vehicles %s", self.config.name, missing)
            return
        self._join_deadline = None
        self._routed = True
        by_peer: dict[_Peer, list[p.BeginTickAC]] = {}
        mine: list[p.BeginTickAC] = []
        for m in self._bta:
            if m.vehicle in local:
                mine.append(m)
            else:
                by_peer.setdefault(holders[m.vehicle], []).append(m)
        now = real_monotonic_ns()
        for peer, msgs in by_peer.items():
            n = len(msgs)
            data = p.encode_many([m if m.count == n else _with_count(m, n) for m in msgs])
            self._wait_ac[peer] = {m.vehicle for m in msgs}
            self._set_deadline(peer, now + int(self.config.stall_timeout_s * NS_PER_S))
            peer.waiting_for = f"END-TICK-AC of tick {self._tick}"
            self._send_raw(peer, data)
        self._flush_dirty()  # BEGIN-TICK-0 and remote BEGIN-TICK-AC go out before the local autopilots run
        for m in mine:  # in-process autopilots answer while the remote ones and the missions work
            self._etas[m.vehicle] = self._step_local(m)

    def _step_local(self, m: p.BeginTickAC) -> p.EndTickAC:
        eta = self._local_autopilots[m.vehicle](m)
        if eta.t_ns != m.t_ns or eta.vehicle != m.vehicle:
            raise _Fatal(f"in-process autopilot of vehicle {m.vehicle} answered for {eta.vehicle} at {eta.t_ns}")
        return eta

    def _start_phase0(self) -> None:
        if self._phase0_started:
            return
        self._phase0_started = True
        msg = p.encode(p.BeginTick0(self._t_ns, self._tick))
        deadline = real_monotonic_ns() + int(self.config.stall_timeout_s * NS_PER_S)
        self._trace("bt0", None)
        t = self._t_ns
        for peer in list(self._active(p.PeerKind.TYPE0, p.PeerKind.CHILD)):
            if (
                peer.kind == p.PeerKind.TYPE0
                and peer.idle_until_ns > t
                and not peer.woken
                and not (peer.delivered and peer.deliver_wakes)
            ):
                continue  # idle by its own lookahead: nothing of it can run in this phase
            peer.woken = peer.delivered = False
            self._wait0.add(peer)
            self._set_deadline(peer, deadline)
            peer.waiting_for = f"END-TICK-0 of tick {self._tick}"
            self._send_raw(peer, msg)

    def _start_phase1(self, parent_msg: p.BeginTick1 | None) -> None:
        self._phase1_started = True
        self._p1_t_ns = self._t_ns
        carrying = bool(parent_msg.packets if parent_msg is not None else self._packets)
        t = self._t_ns
        peers = [
            peer
            for peer in self._active(p.PeerKind.TYPE1, p.PeerKind.CHILD)
            if carrying or peer.kind != p.PeerKind.TYPE1 or peer.idle_until_ns <= t
        ]
        if not peers:
            return  # every network simulator is idle by its lookahead and nothing was enqueued
        if parent_msg is not None:
            msg = parent_msg
        else:
            positions = tuple(p.VehiclePosition(v, self._positions[v]) for v in sorted(self._positions))
            msg = p.BeginTick1(self._t_ns, self._tick, self.config.phase_period_ns, positions, tuple(self._packets))
        data = p.encode(msg)
        deadline = real_monotonic_ns() + int(self.config.stall_timeout_s * NS_PER_S)
        self._trace("bt1", None)
        for peer in peers:
            self._wait1.add(peer)
            self._set_deadline(peer, deadline)
            peer.waiting_for = f"END-TICK-1 of tick {self._tick}"
            self._send_raw(peer, data)

    def _progress(self) -> None:
        """Advance the tick state machine as far as the answers received allow."""
        if not self._in_tick:
            return
        if not self._phase0_started and self._phase0_may_start():
            self._start_phase0()  # the previous phase 1 has just ended
        if self._bta and not self._routed and len(self._bta) >= self._bta_count:
            self._route_ticks()
            if not self._phase0_started and self._phase0_may_start():
                self._start_phase0()  # after the in-process autopilots of this tick
        acs_done = self._routed and not self._wait_ac
        if self._phase0_started and not self._phase0_done and not self._wait0:
            if self._up is not None and self._up.kind == p.PeerKind.CHILD:
                self._phase0_done = True
                self._send(self._up, p.EndTick0(self._t_ns))
            elif acs_done:
                self._phase0_done = True
        if self._up is not None and self._up.kind == p.PeerKind.CHILD:
            self._progress_child(acs_done)
        else:
            self._progress_root(acs_done)

    def _progress_root(self, acs_done: bool) -> None:
        if not acs_done:
            return
        if self._phase_tick:
            if not self._phase0_done:
                return
            if not self._phase1_started:
                self._start_phase1(None)
            if self._wait1 and not self._may_overlap_phase1():
                return
        self._finish_tick()

    def _may_overlap_phase1(self) -> bool:
        """Physics may go on while phase 1 runs (``overlap_phase1``), but not while a child channel is in it:
        a child takes the next BEGIN-TICK-AC only once its tick, phase 1 included, is over."""
        return self.config.overlap_phase1 and all(peer.kind != p.PeerKind.CHILD for peer in self._wait1)

    def _progress_child(self, acs_done: bool) -> None:
        if acs_done and not self._etas_sent_up and self._bta:
            self._etas_sent_up = True
            assert self._up is not None
            self._send_raw(self._up, p.encode_many([self._etas[v] for v in sorted(self._etas)]))
        if self._phase1_started and not self._wait1:
            assert self._up is not None
            self._send(self._up, p.EndTick1(self._t_ns))
            self._phase1_started = False
            self._end_tick_state()
        elif not self._phase0_started and self._etas_sent_up:
            self._end_tick_state()  # a tick without phases ends when the autopilots have answered

    def _finish_tick(self) -> None:
        assert self._up is not None
        self._trace("eta_up", None)
        if self._local:
            self._tick_result = [self._etas[v] for v in sorted(self._etas)]
        elif self._etas:
            self._send_raw(self._up, p.encode_many([self._etas[v] for v in sorted(self._etas)]))
        self._end_tick_state()

    def _end_tick_state(self) -> None:
        self._in_tick = False
        self.ticks_done += 1
        self._admit_pending()

    # -- faults and the watchdog ---------------------------------------------------------------

    def _set_deadline(self, peer: _Peer, deadline_ns: int | None) -> None:
        peer.deadline_ns = deadline_ns
        if deadline_ns is None:
            self._deadlines.pop(peer, None)
        else:
            self._deadlines[peer] = deadline_ns

    def _earliest(self) -> int | None:
        earliest = min(self._deadlines.values()) if self._deadlines else None
        if self._join_deadline is not None and (earliest is None or self._join_deadline < earliest):
            earliest = self._join_deadline
        return earliest

    def _next_timeout(self) -> float | None:
        earliest = self._earliest()
        if earliest is None:
            return None
        return max(0.0, (earliest - real_monotonic_ns()) / NS_PER_S)

    def _check_deadlines(self) -> None:
        earliest = self._earliest()
        now = real_monotonic_ns()
        if earliest is None or now < earliest:
            return
        for peer in list(self._deadlines):
            if peer.deadline_ns is not None and now >= peer.deadline_ns and not peer.closed:
                limit = self.config.stall_timeout_s if peer.kind is not None else self.config.handshake_timeout_s
                self._peer_fault(peer, f"stalled: no {peer.waiting_for} within {limit:g} s", p.ErrorCode.STALLED)
        if self._join_deadline is not None and now >= self._join_deadline:
            missing = sorted({m.vehicle for m in self._bta} - self._held_vehicles())
            raise _Fatal(f"no autopilot joined for vehicles {missing} within {self.config.join_timeout_s:g} s")

    def _peer_lost(self, peer: _Peer, why: str) -> None:
        if peer.upstream:
            if self._up is not None and self._up.kind == p.PeerKind.PHYSICS:
                log.info("channel %s: physics %s", self.config.name, why)
                self._broadcast_bye("physics left")
                self._stop.set()
                self._close_peer(peer)
                return
            raise _Fatal(f"lost the parent channel: {why}")
        self._peer_fault(peer, why, p.ErrorCode.PEER_LOST)

    def _peer_fault(self, peer: _Peer, why: str, code: p.ErrorCode) -> None:
        """Drop ``peer`` (type 0, optionally type 1) or fail the run (everything else)."""
        if peer.closed:
            return
        if peer.upstream:
            raise _Fatal(f"upstream {why}")
        kind = peer.kind
        fatal = kind in (p.PeerKind.AUTOPILOT, p.PeerKind.CHILD) or (
            kind == p.PeerKind.TYPE1 and self.config.type1_fault == "fail"
        )
        message = f"{peer.label}{_vehicle_note(peer)} {why}"
        self.faults.append(
            Fault(peer.name, kind.name if kind is not None else "HANDSHAKE", peer.vehicle, why, self._tick, fatal)
        )
        if kind is None:
            log.warning("channel %s: dropped a connection before its subscription: %s", self.config.name, why)
        else:
            log.error("channel %s: %s", self.config.name, message)
        with contextlib.suppress(OSError):
            peer.sock.send(p.encode(p.Error(code, message, fatal=True)))
        self._close_peer(peer)
        if kind == p.PeerKind.TYPE0:
            self.mission_exits.append(MissionExit(peer.name, peer.vehicle, -1, f"dropped: {why}"))
        if fatal:
            raise _Fatal(message)
        self._announce_up()
        self._progress()

    def _close_peer(self, peer: _Peer) -> None:
        if peer.closed:
            return
        if peer.out and not peer.send_error:
            with contextlib.suppress(OSError):  # best effort: what was queued for it (an ERROR saying why)
                peer.sock.send(peer.out)
        peer.out.clear()
        peer.closed = True
        self._membership_changed()
        self._set_deadline(peer, None)
        self._wait0.discard(peer)
        self._wait1.discard(peer)
        self._wait_ac.pop(peer, None)
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(peer.sock)
        with contextlib.suppress(OSError):
            peer.sock.close()
        self._peers.pop(peer.pid, None)
        if peer is self._up:
            self._up = None

    def _broadcast_bye(self, reason: str) -> None:
        self._flush_dirty()
        data = p.encode(p.Bye(reason))
        for peer in list(self._peers.values()):
            if not peer.upstream:
                with contextlib.suppress(OSError):
                    peer.sock.send(data)

    def _fail_run(self, message: str) -> None:
        self._flush_dirty()
        self.failure = message
        log.error("channel %s: run failed: %s", self.config.name, message)
        data = p.encode(p.Error(p.ErrorCode.PEER_LOST, message, fatal=True))
        for peer in list(self._peers.values()):
            with contextlib.suppress(OSError):
                peer.sock.send(data)

    def _close_all(self) -> None:
        if self._closed_all:
            return
        self._closed_all = True
        for peer in list(self._peers.values()):
            self._close_peer(peer)
        for s in (self._server, self._wake_r, self._wake_w):
            if s is not None:
                with contextlib.suppress(OSError):
                    s.close()
        self._sel.close()
        if self._bound is not None and self._bound.scheme == "unix":
            with contextlib.suppress(OSError):
                os.unlink(self._bound.path)

    def _trace(self, event: str, peer: _Peer | None) -> None:
        if self.config.trace:
            self.trace.append((real_monotonic_ns(), event, self._tick, peer.name if peer else ""))

    def subscribers(self) -> list[tuple[str, str]]:
        """(name, kind) of every admitted peer below this channel (safe to call from another thread)."""
        return [
            (peer.name, peer.kind.name)
            for peer in list(self._peers.values())
            if peer.kind is not None and peer.admitted and not peer.upstream
        ]

    def tree_size(self) -> int:
        """Admitted subscribers in the whole tree below this channel: its own, and what each child announced."""
        return sum(
            1 + (peer.members if peer.kind == p.PeerKind.CHILD else 0)
            for peer in list(self._peers.values())
            if peer.kind is not None and peer.admitted and not peer.upstream and not peer.closed
        )

    def raise_if_failed(self) -> None:
        if self.failure:
            raise SimulationError(self.failure)


def _by_vehicle(eta: p.EndTickAC) -> int:
    return eta.vehicle


def _with_count(m: p.BeginTickAC, n: int) -> p.BeginTickAC:
    return p.BeginTickAC(m.t_ns, m.tick, m.vehicle, n, m.position_ned_m, m.frame)


def _vehicle_note(peer: _Peer) -> str:
    if peer.kind == p.PeerKind.TYPE0 and peer.vehicle >= 0:
        return f" (vehicle {peer.vehicle})"
    if peer.vehicles:
        return f" (vehicles {sorted(peer.vehicles)})"
    return ""


def connect_child_socket(address: str) -> socket.socket:
    """Open a raw connection to a channel (tests of malformed input)."""
    return connect(parse_address(address))
