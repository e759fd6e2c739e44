"""Property tests of the tick machine: Hypothesis drives it with random joins, leaves, answers in any order,
lookahead, packets, stalls and lost peers, and the rig checks on every action (tests/channel/rig.py) that
type-0 and type-1 phases never overlap, no tick ends before every answer and sim time never goes back.
The rules below add: a lost or stalled peer always ends in a fault that names it (and a fatal one in a
failed run that names it too); with every answer given, a tick always ends (no deadlock); every packet
enqueued in a phase 0 is in the next BEGIN-TICK-1.
"""

from __future__ import annotations

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from harness.channel.events import TickState
from harness.wire import protocol as p

from .rig import TICK_NS, Peer, Rig

T0, T1, AP, CHILD = p.PeerKind.TYPE0, p.PeerKind.TYPE1, p.PeerKind.AUTOPILOT, p.PeerKind.CHILD

LOOKAHEAD = st.sampled_from([p.EVERY_PHASE, p.EVERY_PHASE, 2 * TICK_NS, 7 * TICK_NS, p.NO_DEADLINE])


class TickMachineRules(RuleBasedStateMachine):
    rig: Rig

    @initialize(
        vehicles=st.integers(1, 4),
        phase_every=st.integers(1, 3),
        overlap=st.booleans(),
        type1_fault=st.sampled_from(["fail", "drop"]),
        split=st.sampled_from(["one", "each", "in-process", "child"]),
    )
    def setup(self, vehicles: int, phase_every: int, overlap: bool, type1_fault: str, split: str) -> None:
        self.rig = Rig(vehicles, phase_every, overlap, type1_fault)
        self.serial = 0
        self.enqueued: list[p.Packet] = []
        self.lost: list[tuple[str, p.PeerKind]] = []
        vs = tuple(range(vehicles))
        if split == "one":
            self.rig.join(AP, "ap", vehicles=vs)
        elif split == "each":
            for v in vs:
                self.rig.join(AP, f"ap{v}", vehicles=(v,))
        elif split == "in-process":
            self.rig.in_process(vs[: (vehicles + 1) // 2])
            if vehicles > 1:
                self.rig.join(AP, "ap", vehicles=vs[(vehicles + 1) // 2 :])
        else:
            self.rig.join(CHILD, "child", vehicles=vs)

    def _name(self, prefix: str) -> str:
        self.serial += 1
        return f"{prefix}{self.serial}"

    def _live(self, *kinds: p.PeerKind) -> list[Peer]:
        return [peer for peer in self.rig.live() if peer.state.kind in kinds]

    def _running(self) -> bool:
        return self.rig.failure is None

    # -- membership ------------------------------------------------------------------------------------------

    @precondition(lambda self: self._running())
    @rule(vehicle=st.integers(-1, 3))
    def join_mission(self, vehicle: int) -> None:
        self.rig.join(T0, self._name("m"), vehicle=vehicle)

    @precondition(lambda self: self._running() and len(self._live(T1)) < 2)
    @rule()
    def join_network(self) -> None:
        self.rig.join(T1, self._name("net"))

    @precondition(lambda self: self._running() and self._live(T0))
    @rule(data=st.data(), code=st.integers(-1, 3))
    def mission_leaves(self, data: st.DataObject, code: int) -> None:
        peer = data.draw(st.sampled_from(self._live(T0)))
        self.rig.send(peer, p.Bye("done", code))
        assert peer.closed and any(e.peer == peer.name and e.exit_code == code for e in self.rig.machine.mission_exits)

    @precondition(lambda self: self._running() and self.rig.live())
    @rule(data=st.data())
    def peer_is_lost(self, data: st.DataObject) -> None:
        peer = data.draw(st.sampled_from(self.rig.live()))
        self.rig.lose(peer, "connection broke")
        self._check_fault_names(peer)

    @precondition(lambda self: self._running() and self.rig.watchdog.next_deadline_ns() is not None)
    @rule(now=st.integers(0, 3))
    def everyone_late_stalls(self, now: int) -> None:
        """The clock runs past the earliest deadline: whoever it was for is faulted by name."""
        if now:
            return  # (most draws: not yet, so that runs get long before a fault ends them)
        for key in self.rig.stall():
            peer = self.rig.peers.get(key)
            if peer is not None:
                self._check_fault_names(peer)

    def _check_fault_names(self, peer: Peer) -> None:
        assert peer.closed or self.rig.failure is not None
        faults = [f for f in self.rig.machine.faults if f.peer == peer.name]
        assert faults, f"{peer.name} was lost without a fault naming it"
        if faults[-1].fatal:
            assert self.rig.failure is not None and repr(peer.name) in self.rig.failure
        else:
            assert peer.error and repr(peer.name) in peer.error  # it was told why
        if peer.state.kind == T0:
            assert any(e.peer == peer.name and e.exit_code == -1 for e in self.rig.machine.mission_exits)

    # -- the tick ---------------------------------------------------------------------------------------------------

    @precondition(lambda self: self._running() and self.rig.machine.state.tick is TickState.IDLE)
    @rule()
    def physics_begins_a_tick(self) -> None:
        self.rig.begin_tick()

    @precondition(lambda self: self._running() and any(peer.owes_ac for peer in self.rig.live()))
    @rule(data=st.data())
    def autopilot_answers(self, data: st.DataObject) -> None:
        peer = data.draw(st.sampled_from([peer for peer in self.rig.live() if peer.owes_ac]))
        self.rig.answer_ac(peer)

    @precondition(lambda self: self._running() and self.rig.owing0())
    @rule(data=st.data(), idle=LOOKAHEAD, packets=st.integers(0, 2))
    def mission_ends_phase0(self, data: st.DataObject, idle: int, packets: int) -> None:
        peer = data.draw(st.sampled_from([peer for peer in self.rig.live() if peer.owes0 is not None]))
        assert peer.owes0 is not None
        if peer.state.kind == T0:
            self.enqueued += [
                p.Packet(peer.owes0, peer.state.vehicle, p.BROADCAST, 14550, k, b"x") for k in range(packets)
            ]
            self.rig.answer0(peer, idle, packets)
        else:
            self.rig.answer0(peer)
        if self.rig.failure is None:
            self._check_packets()

    def _check_packets(self) -> None:
        """A BEGIN-TICK-1 carries exactly the packets enqueued in its tick's phase 0, in order."""
        for peer in self.rig.live():
            bt1 = [msg for msg in peer.inbox if isinstance(msg, p.BeginTick1)]
            if bt1:
                assert list(bt1[-1].packets) == [pkt for pkt in self.enqueued if pkt.t_ns == bt1[-1].t_ns]

    @precondition(lambda self: self._running() and self.rig.owing1())
    @rule(data=st.data(), idle=LOOKAHEAD, deliver=st.booleans())
    def network_ends_phase1(self, data: st.DataObject, idle: int, deliver: bool) -> None:
        peer = data.draw(st.sampled_from([peer for peer in self.rig.live() if peer.owes1 is not None]))
        if deliver and peer.state.kind == T1:
            pkt = p.Packet(0, 0, 0, 14550, 0, b"r")
            self.rig.send(peer, p.Deliver(peer.owes1 or 0, pkt))
            for m in self._live(T0):
                if m.state.vehicle == 0 and m.state.admitted:
                    assert isinstance(m.inbox[-1], p.Deliver | p.BeginTick0 | p.BeginTick1)
        if not peer.closed:
            self.rig.answer1(peer, idle if peer.state.kind == T1 else p.EVERY_PHASE)

    @precondition(lambda self: self._running() and self._live(T0))
    @rule(data=st.data())
    def mission_wakes(self, data: st.DataObject) -> None:
        self.rig.send(data.draw(st.sampled_from(self._live(T0))), p.Wake())

    @precondition(lambda self: self._running() and self._live(T0, T1))
    @rule(data=st.data())
    def peer_speaks_out_of_turn(self, data: st.DataObject) -> None:
        peer = data.draw(st.sampled_from(self._live(T0, T1)))
        if peer.owes0 is None and peer.owes1 is None:
            self.rig.send(peer, p.EndTick0(self.rig.machine.t_ns + 1))
            self._check_fault_names(peer)

    @precondition(lambda self: not self._running())
    @rule()
    def failed_run_says_why(self) -> None:
        """A failed run names the peer (or the upstream, or the vehicles without autopilot) that ended it."""
        failure = self.rig.failure or ""
        named = [peer.name for peer in self.rig.peers.values() if repr(peer.name) in failure]
        assert named or "upstream" in failure or "no autopilot joined" in failure, failure

    # -- invariants ---------------------------------------------------------------------------------------------------

    @invariant()
    def a_tick_with_every_answer_in_has_ended(self) -> None:
        """Liveness: while nobody owes the machine an answer, no tick is left hanging."""
        rig = self.rig
        if rig.failure is not None or not hasattr(rig, "machine"):
            return
        owing = rig.owing_ac() or rig.owing0() or rig.owing1()
        if not owing and rig.machine.state.tick is not TickState.AWAITING_HOLDERS:
            assert rig.machine.state.tick is TickState.IDLE, f"tick {rig.tick} hangs in {rig.machine.state.tick}"
            assert rig.ticks_ended() == rig.tick + 1

    @invariant()
    def machine_and_rig_agree_on_who_is_awaited(self) -> None:
        rig = self.rig
        if rig.failure is not None:
            return
        m = rig.machine
        assert sorted(peer.name for peer in m.wait0) == sorted(rig.owing0())
        assert sorted(peer.name for peer in m.wait1) == sorted(rig.owing1())
        keys = {peer.state.pid for peer in rig.live() if peer.owes0 is not None or peer.owes1 is not None}
        keys |= {peer.state.pid for peer in rig.live() if peer.owes_ac}
        assert all(rig.watchdog.watching(k) for k in keys), "an awaited peer has no deadline"


TickMachineRules.TestCase.settings = settings(
    max_examples=150, stateful_step_count=50, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
test_tick_machine = TickMachineRules.TestCase
