"""The channel's tick as a sans-I/O state machine (the paper's GZUAVCHANNEL without its sockets).

Events go in as method calls: a peer joined (:meth:`TickMachine.join`), a message from upstream
(:meth:`~TickMachine.from_upstream`) or from a peer below (:meth:`~TickMachine.receive`), the answers of
in-process autopilots (:meth:`~TickMachine.local_answers`), a lost peer (:meth:`~TickMachine.lost`), a
malformed stream (:meth:`~TickMachine.malformed`), an expired wait (:meth:`~TickMachine.expired`,
:meth:`~TickMachine.join_expired`). Actions come out in :attr:`TickMachine.actions` (see
:mod:`harness.channel.events`) for the shell to carry out, in order. A fatal fault raises
:class:`~harness.channel.events.RunFailed`. No sockets, no clock: the only time the machine knows is sim
time from the messages; waits are armed on an injected :class:`~harness.channel.watchdog.Watchdog`.

A tick (docs/channel.md): :class:`TickState` follows the autopilots (IDLE → COLLECTING →
[AWAITING_HOLDERS] → STEPPING → ANSWERED → IDLE), :class:`PhaseState` the subscribers (NONE, or PENDING →
ZERO → ZERO_DONE → ONE). A root decides the phases (every ``phase_every``-th tick); a child obeys its
parent's BEGIN-TICK-0/1 and answers for its subtree.
"""

from __future__ import annotations

import logging
import operator
from collections.abc import Callable, Iterable

from harness.channel.config import Fault, MissionExit
from harness.channel.events import (
    Action,
    Close,
    PeerLink,
    PeerState,
    Phase,
    PhaseState,
    Refused,
    Role,
    RunFailed,
    StepLocal,
    Stop,
    TickDone,
    TickState,
)
from harness.channel.membership import Membership
from harness.channel.state import PhaseEvent, TickEvent, TickProgress
from harness.channel.watchdog import JOIN, Watchdog
from harness.wire import protocol as p

log = logging.getLogger(__name__)

_END_EVENT = {Phase.ZERO: "et0", Phase.ONE: "et1"}

Trace = Callable[[str, int, str], None]
"""(event, tick, peer name): called on every phase transition when tracing."""


class TickMachine(Membership):
    """The tick of one channel. ``actions`` fills as events arrive; the shell drains it."""

    def __init__(
        self,
        watchdog: Watchdog,
        *,
        name: str = "channel",
        phase_every: int = 1,
        phase_period_ns: int = 4_000_000,
        stall_timeout_s: float = 10.0,
        join_timeout_s: float = 30.0,
        type1_fault: str = "fail",
        overlap_phase1: bool = True,
        trace: Trace | None = None,
    ) -> None:
        super().__init__(name)
        self.watchdog = watchdog
        self.phase_every = phase_every
        self.phase_period_ns = phase_period_ns
        self.stall_timeout_s = stall_timeout_s
        self.join_timeout_s = join_timeout_s
        self.type1_fault = type1_fault
        self.overlap_phase1 = overlap_phase1
        self._trace_fn = trace
        self.faults: list[Fault] = []
        self.ticks_done = 0
        self.state = TickProgress()
        """Both halves of the current tick (``state.tick``, ``state.phase``), moved only by the tables of
        :mod:`harness.channel.state`."""
        self.t_ns = -1
        self.tick = -1
        self.p1_t_ns = -1
        self.p1_tick = -1
        """Sim time of the last phase 1 started (it may still run while physics goes on: ``overlap_phase1``)."""
        self.wait0: set[PeerState] = set()
        self.wait1: set[PeerState] = set()
        self.wait_ac: dict[PeerState, set[int]] = {}
        self._bta: list[p.BeginTickAC] = []
        self._bta_count = 0
        self._etas: dict[int, p.EndTickAC] = {}
        self._packets: list[p.Packet] = []
        self._positions: dict[int, p.Vec3] = {}
        self._mavlink_told: set[int] = set()
        """Vehicles whose autopilot says whether it sent its missions MAVLink (END-TICK-AC ``mavlink``)."""
        self._mavlink_sent: set[int] = set()
        """Vehicles that sent their missions MAVLink since those missions' last phase 0."""

    @property
    def phase1_running(self) -> bool:
        """Peers are still in the last phase 1 (it may run beside physics: ``overlap_phase1``)."""
        return bool(self.wait1)

    @property
    def in_tick(self) -> bool:
        return self.state.tick is not TickState.IDLE

    def drain(self) -> list[Action]:
        out, self.actions = self.actions, []
        return out

    # -- membership events -------------------------------------------------------------------------

    def join(self, pid: int, hello: p.Hello) -> PeerState:
        """A peer proved itself (the shell checked version and secret): admit it or raise :class:`Refused`."""
        kind = p.PeerKind(hello.kind)
        if kind == p.PeerKind.PHYSICS and self.up is not None:
            raise Refused(p.ErrorCode.UNEXPECTED, "this channel already has a clock owner")
        if kind == p.PeerKind.AUTOPILOT:
            if not hello.vehicles:
                raise Refused(p.ErrorCode.UNEXPECTED, "an autopilot must hold at least one vehicle")
            taken = set(hello.vehicles) & self.held_vehicles()
            if taken:
                raise Refused(p.ErrorCode.UNEXPECTED, f"vehicles {sorted(taken)} already have an autopilot")
        peer = PeerState(pid, hello.name, kind, vehicle=hello.vehicle, vehicles=set(hello.vehicles))
        self.peers[pid] = peer
        log.info("channel %s: %s joined (vehicles %s)", self.name, peer.label, sorted(peer.vehicles))
        if kind == p.PeerKind.PHYSICS:
            peer.upstream = peer.admitted = True
            self.set_upstream(peer)
        elif not self.in_tick or self.state.tick is TickState.AWAITING_HOLDERS:
            self._admit(peer)
            self._progress()
        else:
            self.unadmitted += 1  # joins between two ticks
        return peer

    def attach_upstream(self, pid: int, kind: p.PeerKind, name: str, link: PeerLink = PeerLink.SOCKET) -> PeerState:
        """The upstream this channel was built with: a local physics (``PHYSICS``) or a parent (``CHILD``)."""
        if self.up is not None:
            raise RunFailed(f"channel {self.name} already has an upstream")
        up = PeerState(pid, "parent" if kind == p.PeerKind.CHILD else name, kind, link=link, upstream=True)
        up.admitted = True
        self.peers[pid] = up
        self.set_upstream(up)
        return up

    def attach_in_process(self, pid: int, vehicles: Iterable[int], name: str = "in-process") -> PeerState:
        """Autopilots in the channel's own process, holding ``vehicles``: one more peer, stepped by action."""
        peer = PeerState(pid, name, p.PeerKind.AUTOPILOT, link=PeerLink.IN_PROCESS, vehicles=set(vehicles))
        self.peers[pid] = peer
        self.in_process_peers += 1
        self._admit(peer)
        return peer

    # -- events from below --------------------------------------------------------------------------

    def receive(self, peer: PeerState, msg: p.Message) -> None:
        """A message from an admitted peer below (ignored once it is closed: the rest of its last read)."""
        if peer.closed:
            return
        if isinstance(msg, p.EndTickAC):
            self._on_end_tick_ac(peer, msg)
        elif isinstance(msg, p.EndTick0):
            peer.idle_until_ns, peer.deliver_wakes = msg.idle_until_ns, msg.deliver_wakes
            peer.mavlink_wakes = msg.mavlink_wakes
            self._on_phase_end(peer, msg.t_ns, Phase.ZERO)
        elif isinstance(msg, p.EndTick1):
            peer.idle_until_ns = msg.idle_until_ns
            self._on_phase_end(peer, msg.t_ns, Phase.ONE)
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
            for name, vehicle, code, reason in msg.exits[peer.exits_seen :]:  # missions that ended below it
                self.mission_exits.append(MissionExit(name, vehicle, code, reason))
            peer.exits_seen = max(peer.exits_seen, len(msg.exits))
            self.membership_changed()
            self._announce_up()
            self._progress()
        elif isinstance(msg, p.Bye):
            self._on_bye(peer, msg)
        elif isinstance(msg, p.Error):
            self.fault(peer, f"reported an error: {msg.message}", p.ErrorCode.PEER_LOST)
        else:
            self.fault(peer, f"sent {type(msg).__name__}, which it may not send", p.ErrorCode.UNEXPECTED)

    def local_answers(self, peer: PeerState, begin_ticks: Iterable[p.BeginTickAC], etas: list[p.EndTickAC]) -> None:
        """The END-TICK-AC of in-process autopilots, after a :class:`StepLocal` (one step of the tick for all)."""
        waiting = self.wait_ac.get(peer)
        if waiting is None:
            raise RunFailed(f"in-process autopilots {sorted(peer.vehicles)} answered a tick they were not asked")
        stored = self._etas
        for m, eta in zip(begin_ticks, etas, strict=True):
            _check_local(m, eta)
            waiting.discard(m.vehicle)
            stored[m.vehicle] = eta
            if eta.mavlink != p.MAVLINK_UNKNOWN:
                self._note_mavlink(eta)
        if not waiting:
            self._holder_done(peer)
        self._progress()

    def _on_phase_end(self, peer: PeerState, t_ns: int, phase: Phase) -> None:
        """END-TICK-0 / END-TICK-1: ``peer`` is done with this tick's phase (and only then may say so)."""
        waiting, t_expected = (self.wait0, self.t_ns) if phase is Phase.ZERO else (self.wait1, self.p1_t_ns)
        if peer not in waiting or t_ns != t_expected:
            self.fault(peer, f"sent END-TICK-{phase.value} for t={t_ns} ns out of phase", p.ErrorCode.UNEXPECTED)
            return
        waiting.discard(peer)
        self._answered(peer)
        self._trace(_END_EVENT[phase], peer)
        self._progress()

    def _on_end_tick_ac(self, peer: PeerState, msg: p.EndTickAC) -> None:
        waiting = self.wait_ac.get(peer)
        if msg.t_ns != self.t_ns or waiting is None or msg.vehicle not in waiting:
            self.fault(
                peer, f"sent END-TICK-AC for vehicle {msg.vehicle} at t={msg.t_ns} ns unasked", p.ErrorCode.UNEXPECTED
            )
            return
        if msg.ticks:  # its host steps its physics too: this tick's position comes with the answer
            self._positions[msg.vehicle] = p.last_position(msg.ticks)
        waiting.discard(msg.vehicle)
        self._etas[msg.vehicle] = msg
        if msg.mavlink != p.MAVLINK_UNKNOWN:
            self._note_mavlink(msg)
        if not waiting:
            self._holder_done(peer)
        self._progress()

    def _note_mavlink(self, eta: p.EndTickAC) -> None:
        self._mavlink_told.add(eta.vehicle)
        if eta.mavlink:
            self._mavlink_sent.add(eta.vehicle)

    def _holder_done(self, peer: PeerState) -> None:
        """Every vehicle of ``peer`` answered this tick."""
        del self.wait_ac[peer]
        self._answered(peer)
        if not self.wait_ac:
            self.state.on(TickEvent.ANSWERED)
            if self.role is _CHILD:
                self._send_etas()  # a child answers for its subtree as soon as it can

    def _on_enqueue(self, peer: PeerState, msg: p.Enqueue) -> None:
        if peer not in self.wait0:
            self.fault(peer, "sent ENQUEUE outside its phase 0", p.ErrorCode.UNEXPECTED)
            return
        if self.role is Role.CHILD:
            assert self.up is not None
            self.send(self.up, msg)  # the root collects every packet of the tree
        else:
            self._packets.append(msg.packet)

    def _on_bye(self, peer: PeerState, msg: p.Bye) -> None:
        if peer.kind == p.PeerKind.TYPE0:
            self.mission_exits.append(MissionExit(peer.name, peer.vehicle, msg.exit_code, msg.reason))
            log.info("channel %s: %s left (exit %d) %s", self.name, peer.label, msg.exit_code, msg.reason)
            self.close(peer)
            self._announce_up()
            self._progress()
        elif peer.kind == p.PeerKind.TYPE1 and peer not in self.wait1:
            self.close(peer)
        else:
            self.fault(peer, f"left the run ({msg.reason or 'no reason given'})", p.ErrorCode.PEER_LOST)

    def _route_deliver(self, msg: p.Deliver | p.DeliverMany, source: PeerState | None) -> None:
        dst = msg.dst if isinstance(msg, p.DeliverMany) else msg.packet.dst
        data = p.encode(msg)
        for peer in self.routes().get(dst, ()):
            peer.delivered = True
            self.send_raw(peer, data)
        for peer in self.active(p.PeerKind.CHILD):
            if peer is not source and dst in peer.mission_vehicles:
                self.send_raw(peer, data)
        up = self.up
        if up is not None and up.kind == p.PeerKind.CHILD and source is not up:
            self.send_raw(up, data)

    def _answered(self, peer: PeerState) -> None:
        """``peer`` gave one answer it owed: its deadline ends unless it owes another (a child owes three)."""
        if peer in self.wait_ac:
            peer.waiting_for = f"END-TICK-AC of tick {self.tick}"
        elif peer in self.wait0:
            peer.waiting_for = f"END-TICK-0 of tick {self.tick}"
        elif peer in self.wait1:
            peer.waiting_for = f"END-TICK-1 of tick {self.p1_tick}"
        else:
            self.watchdog.clear(peer.pid)

    # -- events from above ----------------------------------------------------------------------------

    def from_upstream(self, msg: p.Message) -> None:
        """A message from physics or the parent channel."""
        if isinstance(msg, p.BeginTickAC):
            if self.state.tick is _IDLE:
                self._begin_tick(msg.t_ns, msg.tick)
            elif msg.t_ns != self.t_ns or self.state.tick is not _COLLECTING:
                raise RunFailed(f"upstream sent BEGIN-TICK-AC for t={msg.t_ns} ns while tick t={self.t_ns} ns runs")
            self._bta.append(msg)
            self._bta_count = msg.count
            self._positions[msg.vehicle] = msg.position_ned_m
            if len(self._bta) < msg.count and (self.state.phase is not _PENDING or self.in_process_peers):
                return  # more of this tick to come, and nothing can move before they are in
        elif isinstance(msg, p.BeginTick0):  # child: the parent runs phase 0 now
            if self.state.tick is TickState.IDLE:
                self._begin_tick(msg.t_ns, msg.tick)
            self._start_phase0()
        elif isinstance(msg, p.BeginTick1):
            self._start_phase1(msg)
        elif isinstance(msg, p.Deliver | p.DeliverMany):
            self._route_deliver(msg, source=self.up)
        elif isinstance(msg, p.Bye):
            log.info("channel %s: upstream left (%s)", self.name, msg.reason or "end of run")
            self.actions.append(Stop(msg.reason or "end of run"))
        elif isinstance(msg, p.Error):
            raise RunFailed(f"upstream reported: {msg.message}")
        elif isinstance(msg, p.Welcome | p.Challenge):
            pass
        else:
            raise RunFailed(f"upstream sent {type(msg).__name__}, which it may not send")
        self._progress()

    def local_only(self, begin_ticks: list[p.BeginTickAC]) -> PeerState | None:
        """The in-process peer if this tick is nothing but its step (no phase, every vehicle its own): the
        shell then steps it and calls :meth:`local_tick_done` — 4 ticks out of 5 in ``harness run``."""
        if not begin_ticks or self.state.tick is not TickState.IDLE:
            return None
        peer = self.holders().get(begin_ticks[0].vehicle)
        if peer is None or peer.link is not PeerLink.IN_PROCESS:
            return None
        held = peer.vehicles
        return peer if all(m.vehicle in held for m in begin_ticks) else None

    def local_tick_done(self, begin_ticks: list[p.BeginTickAC], etas: list[p.EndTickAC]) -> list[p.EndTickAC]:
        """End a :meth:`local_only` tick: the same checks as the general path, the answers by vehicle."""
        first = begin_ticks[0]
        if first.t_ns < self.t_ns:
            raise RunFailed(f"upstream went back in time ({first.t_ns} ns < {self.t_ns} ns)")
        for m, eta in zip(begin_ticks, etas, strict=True):
            _check_local(m, eta)
            if eta.mavlink != p.MAVLINK_UNKNOWN:
                self._note_mavlink(eta)
        self.t_ns, self.tick = first.t_ns, first.tick
        self._trace("eta_up", None)
        self.ticks_done += 1
        etas.sort(key=_by_vehicle)
        return etas

    # -- faults -------------------------------------------------------------------------------------------

    def expired(self, peer: PeerState) -> None:
        """The watchdog: ``peer`` did not answer in time."""
        self.fault(peer, f"stalled: no {peer.waiting_for} within {self.stall_timeout_s:g} s", p.ErrorCode.STALLED)

    def join_expired(self) -> None:
        missing = sorted({m.vehicle for m in self._bta} - self.held_vehicles())
        raise RunFailed(f"no autopilot joined for vehicles {missing} within {self.join_timeout_s:g} s")

    def malformed(self, peer: PeerState, why: str) -> None:
        self.fault(peer, f"sent a malformed frame ({why})", p.ErrorCode.MALFORMED)

    def lost(self, peer: PeerState, why: str) -> None:
        """``peer``'s connection ended (or broke)."""
        if peer.closed:
            return
        if peer.upstream:
            if peer.kind == p.PeerKind.PHYSICS:
                log.info("channel %s: physics %s", self.name, why)
                self.actions.append(Stop("physics left"))
                self.close(peer)
                return
            raise RunFailed(f"lost the parent channel: {why}")
        self.fault(peer, why, p.ErrorCode.PEER_LOST)

    def fault(self, peer: PeerState, why: str, code: p.ErrorCode) -> None:
        """Drop ``peer`` (type 0, optionally type 1) or fail the run (everything else); the runner reports both."""
        if peer.closed:
            return
        if peer.upstream:
            raise RunFailed(f"upstream {why}")
        kind = peer.kind
        fatal = kind in (p.PeerKind.AUTOPILOT, p.PeerKind.CHILD) or (
            kind == p.PeerKind.TYPE1 and self.type1_fault == "fail"
        )
        message = f"{peer.label}{peer.vehicle_note} {why}"
        self.faults.append(Fault(peer.name, kind.name, peer.vehicle, why, self.tick, fatal))
        log.log(logging.INFO if fatal or kind == p.PeerKind.TYPE0 else logging.ERROR, f"channel {self.name}: {message}")
        self.close(peer, p.encode(p.Error(code, message, fatal=True)))
        if kind == p.PeerKind.TYPE0:
            self.mission_exits.append(MissionExit(peer.name, peer.vehicle, -1, f"dropped: {why}"))
        if fatal:
            raise RunFailed(message)
        self._announce_up()
        self._progress()

    def close(self, peer: PeerState, error: bytes = b"") -> None:
        if peer.closed:
            return
        peer.closed = True
        if peer.link is _IN_PROCESS and not peer.upstream:
            self.in_process_peers -= 1
        self.membership_changed()
        self.watchdog.clear(peer.pid)
        self.wait0.discard(peer)
        self.wait1.discard(peer)
        self.wait_ac.pop(peer, None)
        self.peers.pop(peer.pid, None)
        if peer is self.up:
            self.set_upstream(None)
        self.actions.append(Close(peer, error))

    # -- the tick -------------------------------------------------------------------------------------------

    def _begin_tick(self, t_ns: int, tick: int) -> None:
        if t_ns < self.t_ns:
            raise RunFailed(f"upstream went back in time ({t_ns} ns < {self.t_ns} ns)")
        self._admit_pending()
        state = self.state
        state.on(TickEvent.BEGIN)
        self.t_ns, self.tick = t_ns, tick
        self._bta, self._bta_count = [], 0
        self._etas = {}
        self._packets, self._positions = [], {}
        root = self.role is Role.ROOT
        state.on_phase(
            PhaseEvent.TICK_WITH_PHASES if root and tick % self.phase_every == 0 else PhaseEvent.TICK_WITHOUT_PHASES
        )

    def _phase0_may_start(self) -> bool:
        """Phase 0 starts once the previous phase 1 is over and after the autopilots have stepped this tick:
        what they send their missions over MAVLink at this tick is then in the missions' sockets before phase 0
        begins, so a script reads it in this phase whatever the machine's pace. With no autopilot in-process
        and no child channel, phase 0 overlaps the autopilots' step (the paper's order). A child channel's
        missions are different: the child decides which of them take part from its vehicles' END-TICK-AC
        ``mavlink``, so the root waits for every answer, which passes through the child on its way up, before
        phase 0 (without that wait a MAVSDK mission on a cluster worker armed a phase later in one run of two:
        its child had taken it into phase 0 before its vehicle's answer was in)."""
        if self.state.phase is not _PENDING or self.wait1:
            return False
        if not self.in_process_peers and not any(True for _ in self.active(p.PeerKind.CHILD)):
            return True
        state = self.state.tick
        if state is _COLLECTING or state is _AWAITING:
            return False
        # with autopilots both here and in other processes (``harness run --workers``) the others must have
        # answered too: a command a mission sends in phase 0 then never races a remote autopilot's step
        return not self.wait_ac

    def _route_ticks(self) -> None:
        """Forward this tick's BEGIN-TICK-AC to the holders of the vehicles, with per-holder counts."""
        holders = self.holders()
        missing = sorted({m.vehicle for m in self._bta} - holders.keys())
        if missing:
            if self.state.tick is not TickState.AWAITING_HOLDERS:
                self.state.on(TickEvent.HOLDER_MISSING)
                self.watchdog.watch(JOIN, self.join_timeout_s)
                log.info("channel %s: waiting for autopilots of vehicles %s", self.name, missing)
            return
        self.watchdog.clear(JOIN)
        self.state.on(TickEvent.ROUTED)
        by_peer: dict[PeerState, list[p.BeginTickAC]] = {}
        for m in self._bta:
            by_peer.setdefault(holders[m.vehicle], []).append(m)
        deadline = -1  # read the clock only if a remote holder is asked
        local: list[StepLocal] = []
        for peer, msgs in by_peer.items():
            self.wait_ac[peer] = {m.vehicle for m in msgs}
            if peer.link is _IN_PROCESS:
                local.append(StepLocal(peer, tuple(msgs)))
                continue
            if deadline < 0:
                deadline = self.watchdog.deadline(self.stall_timeout_s)
            n = len(msgs)
            self.watchdog.arm(peer.pid, deadline)
            peer.waiting_for = f"END-TICK-AC of tick {self.tick}"
            self.send_raw(peer, p.encode_many([m if m.count == n else _with_count(m, n) for m in msgs]))
        self.actions += local  # in-process autopilots answer while the remote ones and the missions work

    def _start_phase0(self) -> None:
        if self.state.phase in (PhaseState.ZERO, PhaseState.ZERO_DONE, PhaseState.ONE):
            return
        self.state.on_phase(PhaseEvent.BEGIN0)
        self._trace("bt0", None)
        peers = self.active(p.PeerKind.TYPE0, p.PeerKind.CHILD)
        if not peers:
            return
        data = p.encode(p.BeginTick0(self.t_ns, self.tick))
        deadline = self.watchdog.deadline(self.stall_timeout_s)
        t = self.t_ns
        what = f"END-TICK-0 of tick {self.tick}"
        woken_by_mavlink = []
        for peer in list(peers):
            if peer.kind == p.PeerKind.TYPE0 and not self._needs_phase0(peer, t):
                continue  # idle by its own lookahead: nothing of it can run in this phase
            peer.woken = peer.delivered = False
            if peer.mavlink_wakes:
                woken_by_mavlink.append(peer.vehicle)
            self.wait0.add(peer)
            self.watchdog.arm(peer.pid, deadline)
            peer.waiting_for = what
            self.send_raw(peer, data)
        self._mavlink_sent.difference_update(woken_by_mavlink)  # (after the loop: two missions of one vehicle)

    def _needs_phase0(self, peer: PeerState, t: int) -> bool:
        """Whether a type-0 subscriber takes part in phase 0 at ``t``: its lookahead (END-TICK-0) has a timed wait
        due, a WAKE or a DELIVER it waits for came, or — when it waits for its vehicle's MAVLink — the vehicle sent
        it some since its last phase 0 (or does not say). Decided from what the tick brought, never from the wall
        clock: the same phases at any pace."""
        if peer.idle_until_ns <= t or peer.woken or (peer.delivered and peer.deliver_wakes):
            return True
        if not peer.mavlink_wakes:
            return False
        v = peer.vehicle
        # (a vehicle that has not answered this tick yet — phase 0 may start before remote autopilots answer when
        # none is in-process — may be sending now: the mission takes part, as without the flag)
        return v not in self._mavlink_told or v in self._mavlink_sent or v not in self._etas

    def _start_phase1(self, parent_msg: p.BeginTick1 | None) -> None:
        self.state.on_phase(PhaseEvent.BEGIN1)
        self.p1_t_ns, self.p1_tick = self.t_ns, self.tick
        carrying = bool(parent_msg.packets if parent_msg is not None else self._packets)
        t = self.t_ns
        peers = [
            peer
            for peer in self.active(p.PeerKind.TYPE1, p.PeerKind.CHILD)
            if carrying or peer.kind != p.PeerKind.TYPE1 or peer.idle_until_ns <= t
        ]
        if not peers:
            return  # every network simulator is idle by its lookahead and nothing was enqueued
        if parent_msg is not None:
            msg = parent_msg
        else:
            positions = tuple(p.VehiclePosition(v, self._positions[v]) for v in sorted(self._positions))
            msg = p.BeginTick1(self.t_ns, self.tick, self.phase_period_ns, positions, tuple(self._packets))
        data = p.encode(msg)
        deadline = self.watchdog.deadline(self.stall_timeout_s)
        self._trace("bt1", None)
        what = f"END-TICK-1 of tick {self.tick}"
        for peer in peers:
            self.wait1.add(peer)
            self.watchdog.arm(peer.pid, deadline)
            peer.waiting_for = what
            self.send_raw(peer, data)

    def _progress(self) -> None:
        """Advance the tick as far as the answers received allow (called after every event: kept cheap)."""
        state = self.state.tick
        if state is _IDLE:
            return
        if self.state.phase is _PENDING and self._phase0_may_start():
            self._start_phase0()  # the previous phase 1 has just ended
        if (state is _COLLECTING or state is _AWAITING) and 0 < self._bta_count <= len(self._bta):
            self._route_ticks()
            if self.state.phase is _PENDING and self._phase0_may_start():
                self._start_phase0()
        child = self.role is _CHILD
        if self.state.phase is _ZERO and not self.wait0:
            if child:
                self.state.on_phase(PhaseEvent.END0)
                assert self.up is not None
                self.send(self.up, p.EndTick0(self.t_ns))
            elif self.state.tick is _ANSWERED:
                self.state.on_phase(PhaseEvent.END0)
        if child:
            self._progress_child()
        elif self.state.tick is _ANSWERED:
            self._progress_root()

    def _progress_root(self) -> None:
        phase = self.state.phase
        if phase is PhaseState.PENDING or phase is PhaseState.ZERO:
            return
        if phase is PhaseState.ZERO_DONE:
            self._start_phase1(None)
        if self.state.phase is PhaseState.ONE and self.wait1 and not self._may_overlap_phase1():
            return
        self._finish_tick()

    def _may_overlap_phase1(self) -> bool:
        """Physics may go on while phase 1 runs (``overlap_phase1``), but not while a child channel is in it:
        a child takes the next BEGIN-TICK-AC only once its tick, phase 1 included, is over."""
        return self.overlap_phase1 and all(peer.kind != p.PeerKind.CHILD for peer in self.wait1)

    def _progress_child(self) -> None:
        if self.state.phase is PhaseState.ONE:
            if not self.wait1:
                assert self.up is not None
                self.send(self.up, p.EndTick1(self.t_ns))
                self._end_tick()
        elif self.state.phase is PhaseState.NONE and self.state.tick is TickState.ANSWERED:
            self._end_tick()  # a tick without phases ends when the autopilots have answered

    def _send_etas(self) -> None:
        if self._etas:
            assert self.up is not None
            self.send_raw(self.up, p.encode_many([self._etas[v] for v in sorted(self._etas)]))

    def _finish_tick(self) -> None:
        up = self.up
        assert up is not None
        self._trace("eta_up", None)
        if up.link is PeerLink.IN_PROCESS:
            self.actions.append(TickDone(tuple(self._etas[v] for v in sorted(self._etas))))
        else:
            self._send_etas()
        self._end_tick()

    def _end_tick(self) -> None:
        self.state.on(TickEvent.END)
        self.ticks_done += 1
        self._admit_pending()

    def _trace(self, event: str, peer: PeerState | None) -> None:
        if self._trace_fn is not None:
            self._trace_fn(event, self.tick, peer.name if peer else "")


# the states the hot path compares against, bound once (a module global is one lookup, an enum member two)
_IDLE, _COLLECTING, _AWAITING = TickState.IDLE, TickState.COLLECTING, TickState.AWAITING_HOLDERS
_ANSWERED, _PENDING, _ZERO, _CHILD = TickState.ANSWERED, PhaseState.PENDING, PhaseState.ZERO, Role.CHILD
_by_vehicle = operator.attrgetter("vehicle")
_IN_PROCESS = PeerLink.IN_PROCESS


def _with_count(m: p.BeginTickAC, n: int) -> p.BeginTickAC:
    return p.BeginTickAC(m.t_ns, m.tick, m.vehicle, n, m.position_ned_m, m.frame)


def _check_local(m: p.BeginTickAC, eta: p.EndTickAC) -> None:
    if eta.t_ns != m.t_ns or eta.vehicle != m.vehicle:
        raise RunFailed(f"in-process autopilot of vehicle {m.vehicle} answered for {eta.vehicle} at {eta.t_ns}")


__all__ = ["Refused", "RunFailed", "TickMachine"]
