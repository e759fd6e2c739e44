"""A rig around the sans-I/O tick machine: peers are plain records, time is a ManualClock.

It carries out the machine's actions the way the shell does (bytes decoded into each peer's inbox, in-process
autopilots stepped, closes and tick results noted) and checks, on every action, what the machine promises:
type-0 and type-1 phases never overlap, a tick ends only after every answer, sim time never goes back, a
closed peer is sent nothing more.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from harness.channel.events import Close, PeerLink, PeerState, RunFailed, Send, StepLocal, Stop, TickDone
from harness.channel.machine import TickMachine
from harness.channel.watchdog import Watchdog
from harness.core.clock import NS_PER_S, ManualClock
from harness.wire import protocol as p

TICK_NS = 4_000_000
STALL_S = 1.0


@dataclass
class Peer:
    """A peer as the rig plays it: what it was sent, what it still owes."""

    state: PeerState
    inbox: list[p.Message] = field(default_factory=list)
    owes_ac: dict[int, p.BeginTickAC] = field(default_factory=dict)
    owes0: int | None = None
    """t_ns of a BEGIN-TICK-0 not yet answered."""
    owes1: int | None = None
    closed: bool = False
    error: str = ""

    @property
    def name(self) -> str:
        return self.state.name


class Rig:
    def __init__(
        self,
        vehicles: int = 1,
        phase_every: int = 1,
        overlap_phase1: bool = True,
        type1_fault: str = "fail",
    ) -> None:
        self.clock = ManualClock()
        self.watchdog = Watchdog(self.clock)
        self.machine = TickMachine(
            self.watchdog,
            phase_every=phase_every,
            phase_period_ns=phase_every * TICK_NS,
            stall_timeout_s=STALL_S,
            join_timeout_s=5 * STALL_S,
            type1_fault=type1_fault,
            overlap_phase1=overlap_phase1,
        )
        self.machine.attach_upstream(0, p.PeerKind.PHYSICS, "physics", PeerLink.IN_PROCESS)
        self.vehicles = vehicles
        self.overlap_phase1 = overlap_phase1
        self.peers: dict[int, Peer] = {}
        self.next_pid = 1
        self.tick = -1
        self.done: list[tuple[p.EndTickAC, ...]] = []
        self.stopped: list[str] = []
        self.failure: str | None = None
        self.local_steps: dict[int, Callable[[p.BeginTickAC], p.EndTickAC]] = {}
        self.last_phase_t = -1
        self.phases: list[tuple[str, int]] = []
        """("bt0" | "bt1", t_ns) in the order they went out."""

    # -- building ---------------------------------------------------------------------------------------

    def join(self, kind: p.PeerKind, name: str, vehicle: int = -1, vehicles: tuple[int, ...] = ()) -> Peer:
        pid = self.next_pid
        self.next_pid += 1
        hello = p.Hello(p.PROTOCOL_VERSION, kind, name, vehicle, vehicles)
        state = self.machine.join(pid, hello)
        peer = self.peers[pid] = Peer(state)
        self.run()
        return peer

    def in_process(self, vehicles: tuple[int, ...], motors: float = 0.5) -> PeerState:
        pid = self.next_pid
        self.next_pid += 1
        for v in vehicles:
            self.local_steps[v] = lambda m: p.EndTickAC(m.t_ns, m.vehicle, (motors,) * 4)
        return self.machine.attach_in_process(pid, vehicles)

    # -- events -------------------------------------------------------------------------------------------

    def guarded(self, event: Callable[[], None]) -> None:
        """Feed one event; a fatal fault is noted (``failure``), not raised."""
        if self.failure is not None:
            return
        try:
            event()
            self.run()
        except RunFailed as exc:
            self.failure = str(exc)

    def begin_tick(self) -> None:
        """Physics: BEGIN-TICK-AC of the next tick for every vehicle."""
        self.tick += 1
        t = self.tick * TICK_NS
        n = self.vehicles
        for v in range(n):
            msg = p.BeginTickAC(t, self.tick, v, n, (float(v), 0.0, -1.0))
            self.guarded(lambda msg=msg: self.machine.from_upstream(msg))  # type: ignore[misc]

    def send(self, peer: Peer, msg: p.Message) -> None:
        self.guarded(lambda: self.machine.receive(peer.state, msg))

    def answer_ac(self, peer: Peer, mavlink: int = p.MAVLINK_UNKNOWN) -> None:
        owed = sorted(peer.owes_ac.values(), key=lambda m: m.vehicle)
        peer.owes_ac.clear()
        for m in owed:
            self.send(peer, p.EndTickAC(m.t_ns, m.vehicle, (0.5,) * 4, 0, b"", mavlink))

    def answer0(
        self, peer: Peer, idle_until_ns: int = p.EVERY_PHASE, packets: int = 0, mavlink_wakes: bool = False
    ) -> None:
        t = peer.owes0
        assert t is not None
        for k in range(packets):
            self.send(peer, p.Enqueue(p.Packet(t, peer.state.vehicle, p.BROADCAST, 14550, k, b"x")))
        peer.owes0 = None
        self.send(peer, p.EndTick0(t, idle_until_ns, True, mavlink_wakes))

    def answer1(self, peer: Peer, idle_until_ns: int = p.EVERY_PHASE) -> None:
        t = peer.owes1
        assert t is not None
        peer.owes1 = None
        self.send(peer, p.EndTick1(t, idle_until_ns))

    def lose(self, peer: Peer, why: str = "disconnected") -> None:
        self.guarded(lambda: self.machine.lost(peer.state, why))

    def stall(self) -> list[int]:
        """Move the clock past the earliest deadline and fire the watchdog like the shell does; the keys handled."""
        deadline = self.watchdog.next_deadline_ns()
        if deadline is None:
            return []
        self.clock.advance_to(max(self.clock.now_ns(), deadline))
        expired = []
        for key in self.watchdog.expired():
            if self.failure is not None:
                break  # the run is over: the shell stops at the first fatal fault
            expired.append(key)
            peer = self.machine.peers.get(key)
            if peer is None:
                self.guarded(self.machine.join_expired)
            else:
                self.guarded(lambda peer=peer: self.machine.expired(peer))  # type: ignore[misc]
        return expired

    def advance_s(self, seconds: float) -> None:
        self.clock.advance_to(self.clock.now_ns() + int(seconds * NS_PER_S))

    # -- actions -------------------------------------------------------------------------------------------

    def run(self) -> None:
        m = self.machine
        while m.actions:
            for action in m.drain():
                if isinstance(action, Send):
                    self._deliver(action.peer, action.data)
                elif isinstance(action, StepLocal):
                    etas = [self.local_steps[b.vehicle](b) for b in action.begin_ticks]
                    m.local_answers(action.peer, action.begin_ticks, etas)
                elif isinstance(action, Close):
                    peer = self.peers.get(action.peer.pid)
                    if peer is not None:
                        peer.closed = True
                        peer.owes_ac.clear()
                        peer.owes0 = peer.owes1 = None
                        if action.error:
                            (err,) = p.FrameDecoder().feed(action.error)
                            assert isinstance(err, p.Error)
                            peer.error = err.message
                elif isinstance(action, TickDone):
                    self._tick_done(action.end_ticks)
                elif isinstance(action, Stop):
                    self.stopped.append(action.reason)

    def _deliver(self, state: PeerState, data: bytes) -> None:
        peer = self.peers[state.pid]
        assert not peer.closed, f"{peer.name} was sent {data!r} after it was closed"
        for msg in p.FrameDecoder().feed(data):
            peer.inbox.append(msg)
            if isinstance(msg, p.BeginTickAC):
                assert msg.vehicle in state.vehicles
                assert msg.vehicle not in peer.owes_ac, "BEGIN-TICK-AC twice for one vehicle and tick"
                peer.owes_ac[msg.vehicle] = msg
            elif isinstance(msg, p.BeginTick0):
                self._phase_starts("bt0", msg.t_ns)
                assert peer.owes0 is None, f"{peer.name}: BEGIN-TICK-0 while its phase 0 runs"
                peer.owes0 = msg.t_ns
            elif isinstance(msg, p.BeginTick1):
                self._phase_starts("bt1", msg.t_ns)
                assert peer.owes1 is None, f"{peer.name}: BEGIN-TICK-1 while its phase 1 runs"
                peer.owes1 = msg.t_ns

    def _phase_starts(self, what: str, t_ns: int) -> None:
        """Type 0 and type 1 never overlap: no phase starts while a peer owes an answer of the other one."""
        if what == "bt0":
            assert not self.owing1(), f"BEGIN-TICK-0 at {t_ns} while phase 1 runs: {self.owing1()}"
        else:
            assert not self.owing0(), f"BEGIN-TICK-1 at {t_ns} while phase 0 runs: {self.owing0()}"
        assert t_ns >= self.last_phase_t, "phases went back in sim time"
        self.last_phase_t = t_ns
        if not self.phases or self.phases[-1] != (what, t_ns):
            self.phases.append((what, t_ns))

    def _tick_done(self, etas: tuple[p.EndTickAC, ...]) -> None:
        """No tick ends before every answer: every END-TICK-AC, every END-TICK-0 and (unless phase 1 may run
        beside physics) every END-TICK-1; one END-TICK-AC per vehicle at this tick's time."""
        t = self.tick * TICK_NS
        assert not self.owing_ac(), f"tick {self.tick} ended while {self.owing_ac()} owe END-TICK-AC"
        assert not self.owing0(), f"tick {self.tick} ended while {self.owing0()} owe END-TICK-0"
        if not self.overlap_phase1:
            assert not self.owing1(), f"tick {self.tick} ended while {self.owing1()} owe END-TICK-1"
        assert [e.vehicle for e in etas] == list(range(self.vehicles))
        assert all(e.t_ns == t for e in etas)
        assert not self.done or self.done[-1][0].t_ns < t, "sim time went back"
        self.done.append(etas)

    # -- queries ----------------------------------------------------------------------------------------------

    def live(self) -> list[Peer]:
        return [peer for peer in self.peers.values() if not peer.closed]

    def owing_ac(self) -> list[str]:
        return [peer.name for peer in self.live() if peer.owes_ac]

    def owing0(self) -> list[str]:
        return [peer.name for peer in self.live() if peer.owes0 is not None]

    def owing1(self) -> list[str]:
        return [peer.name for peer in self.live() if peer.owes1 is not None]

    def ticks_ended(self) -> int:
        return len(self.done)
