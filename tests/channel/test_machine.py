"""The tick machine by example: events in, actions out, no sockets, time on a ManualClock."""

from __future__ import annotations

import pytest

from harness.channel.events import PeerLink, PhaseState, Role, RunFailed, Send, TickDone, TickState
from harness.channel.machine import TickMachine
from harness.channel.watchdog import JOIN, Watchdog
from harness.core.clock import ManualClock
from harness.wire import protocol as p

from .rig import STALL_S, TICK_NS, Rig

T0, T1 = p.PeerKind.TYPE0, p.PeerKind.TYPE1
AP = p.PeerKind.AUTOPILOT


def test_one_tick_runs_the_paper_order_and_ends_after_every_answer() -> None:
    rig = Rig(vehicles=2, overlap_phase1=False)
    ap = rig.join(AP, "ap", vehicles=(0, 1))
    m0 = rig.join(T0, "m0", vehicle=1)
    net = rig.join(T1, "net")
    rig.begin_tick()
    assert sorted(ap.owes_ac) == [0, 1] and m0.owes0 == 0 and net.owes1 is None
    assert rig.machine.state.tick is TickState.STEPPING and rig.machine.state.phase is PhaseState.ZERO
    rig.answer_ac(ap)
    assert net.owes1 is None  # phase 1 waits for phase 0
    rig.answer0(m0, packets=2)
    (bt1,) = [msg for msg in net.inbox if isinstance(msg, p.BeginTick1)]
    assert [pkt.seq for pkt in bt1.packets] == [0, 1] and [vp.vehicle for vp in bt1.positions] == [0, 1]
    assert bt1.positions[1].ned_m == (1.0, 0.0, -1.0) and bt1.period_ns == TICK_NS
    assert rig.ticks_ended() == 0  # strict order: physics waits for END-TICK-1
    rig.answer1(net)
    assert rig.ticks_ended() == 1 and rig.machine.state.tick is TickState.IDLE
    assert rig.phases == [("bt0", 0), ("bt1", 0)]


def test_overlapping_phase1_lets_physics_go_on_but_holds_the_next_phase0() -> None:
    rig = Rig(vehicles=1, overlap_phase1=True)
    ap = rig.join(AP, "ap", vehicles=(0,))
    m0 = rig.join(T0, "m0", vehicle=0)
    net = rig.join(T1, "net")
    rig.begin_tick()
    rig.answer_ac(ap)
    rig.answer0(m0)
    assert net.owes1 == 0 and rig.ticks_ended() == 1  # physics already has its END-TICK-AC
    rig.begin_tick()
    rig.answer_ac(ap)
    assert m0.owes0 is None and rig.machine.state.phase is PhaseState.PENDING  # phase 1 of tick 0 still runs
    rig.answer1(net)
    assert m0.owes0 == TICK_NS
    rig.answer0(m0)
    assert net.owes1 == TICK_NS


def test_in_process_autopilots_step_before_phase0_and_a_quiet_tick_is_only_their_step() -> None:
    rig = Rig(vehicles=2, phase_every=2)
    local = rig.in_process((0, 1))
    assert local.link is PeerLink.IN_PROCESS and rig.machine.subscribers() == []
    m0 = rig.join(T0, "m0", vehicle=0)
    rig.begin_tick()  # tick 0 runs the phases: the in-process autopilots step first, then BEGIN-TICK-0
    assert m0.owes0 == 0 and rig.machine.state.tick is TickState.ANSWERED
    rig.answer0(m0)
    assert rig.ticks_ended() == 1
    bta = [p.BeginTickAC(TICK_NS, 1, v, 2, (0.0, 0.0, 0.0)) for v in (1, 0)]
    assert rig.machine.local_only(bta) is local
    etas = rig.machine.local_tick_done(bta, [p.EndTickAC(TICK_NS, v, (0.1,) * 4) for v in (1, 0)])
    assert [e.vehicle for e in etas] == [0, 1] and rig.machine.ticks_done == 2
    with pytest.raises(RunFailed, match="answered for 0"):
        rig.machine.local_tick_done(bta, [p.EndTickAC(TICK_NS, 0, (0.1,) * 4)] * 2)


def test_lookahead_leaves_an_idle_mission_out_until_its_time_or_a_wake() -> None:
    rig = Rig()
    ap = rig.join(AP, "ap", vehicles=(0,))
    m0 = rig.join(T0, "m0", vehicle=0)
    rig.begin_tick()
    rig.answer_ac(ap)
    rig.answer0(m0, idle_until_ns=3 * TICK_NS)
    for _ in (1, 2):
        rig.begin_tick()
        assert m0.owes0 is None
        rig.answer_ac(ap)
    rig.send(m0, p.Wake())
    rig.begin_tick()  # tick 3, and it asked for 3 anyway
    assert m0.owes0 == 3 * TICK_NS
    rig.answer0(m0, idle_until_ns=p.NO_DEADLINE)
    rig.answer_ac(ap)
    rig.begin_tick()
    assert m0.owes0 is None
    rig.answer_ac(ap)
    rig.send(m0, p.Wake())
    rig.begin_tick()
    assert m0.owes0 == 5 * TICK_NS and rig.failure is None


def test_a_mission_waiting_for_mavlink_runs_after_the_ticks_its_vehicle_sent_it_some() -> None:
    """END-TICK-0 ``mavlink_wakes``: the channel wakes the mission at the phase after its vehicle said (END-TICK-AC
    ``mavlink``) that it sent it MAVLink, at every phase while the vehicle does not say, and at its deadline."""
    rig = Rig(vehicles=2, phase_every=2)
    said = {0: p.MAVLINK_UNKNOWN, 1: 0}
    for v in (0, 1):
        rig.local_steps[v] = lambda m: p.EndTickAC(m.t_ns, m.vehicle, (0.5,) * 4, 0, b"", said[m.vehicle])
    local = rig.machine.attach_in_process(99, (0, 1))
    m0, m1 = rig.join(T0, "m0", vehicle=0), rig.join(T0, "m1", vehicle=1)

    def two_ticks(phase_tick_sent: int, quiet_tick_sent: int) -> None:
        """A tick with phases (in-process autopilots step, then phase 0), then a quiet one (the shell's fast path),
        vehicle 1 saying whether it sent its mission MAVLink in each."""
        said[1] = phase_tick_sent
        rig.begin_tick()
        for peer in (m0, m1):
            if peer.owes0 is not None:
                rig.answer0(peer, idle_until_ns=10 * TICK_NS, mavlink_wakes=True)
        said[1] = quiet_tick_sent
        rig.tick += 1
        bta = [p.BeginTickAC(rig.tick * TICK_NS, rig.tick, v, 2, (0.0, 0.0, 0.0)) for v in (0, 1)]
        assert rig.machine.local_only(bta) is local
        rig.machine.local_tick_done(bta, [rig.local_steps[m.vehicle](m) for m in bta])

    two_ticks(0, 0)  # ticks 0, 1: both missions run (no END-TICK-0 yet)
    two_ticks(0, 0)  # 2, 3: vehicle 0 does not say (m0 runs at every phase); vehicle 1 sent nothing
    two_ticks(1, 0)  # 4, 5: vehicle 1 sent in tick 4 — its step comes before phase 0: m1 runs at 4
    two_ticks(0, 1)  # 6, 7: nothing at 6; tick 7 sent
    two_ticks(0, 0)  # 8, 9: m1 runs at 8 for tick 7
    rig.begin_tick()  # 10: m1's deadline
    received = {
        name: [msg.t_ns // TICK_NS for msg in peer.inbox if isinstance(msg, p.BeginTick0)]
        for name, peer in (("m0", m0), ("m1", m1))
    }
    assert received == {"m0": [0, 2, 4, 6, 8, 10], "m1": [0, 4, 8, 10]} and rig.failure is None


def test_a_mission_waiting_for_mavlink_runs_while_its_vehicle_may_still_be_sending() -> None:
    """Without in-process autopilots phase 0 starts before the remote ones answer: a vehicle that has not answered
    this tick may be sending now, so its mission takes part whatever the vehicle said before."""
    rig = Rig()
    ap = rig.join(AP, "ap", vehicles=(0,))
    m0 = rig.join(T0, "m0", vehicle=0)
    for _ in range(3):
        rig.begin_tick()
        assert m0.owes0 == rig.tick * TICK_NS
        rig.answer0(m0, idle_until_ns=p.NO_DEADLINE, mavlink_wakes=True)
        rig.answer_ac(ap, mavlink=0)
    assert rig.failure is None


def test_a_stalled_mission_is_dropped_by_the_watchdog_and_the_tick_goes_on() -> None:
    rig = Rig()
    ap = rig.join(AP, "ap", vehicles=(0,))
    m0 = rig.join(T0, "sleepy", vehicle=0)
    rig.begin_tick()
    rig.answer_ac(ap)
    rig.advance_s(STALL_S / 2)
    assert rig.watchdog.expired() == []
    assert rig.stall() == [m0.state.pid]
    (fault,) = rig.machine.faults
    assert fault.peer == "sleepy" and not fault.fatal and "END-TICK-0 of tick 0" in fault.reason
    assert "sleepy" in m0.error and m0.closed
    assert rig.machine.mission_exits[0].exit_code == -1 and rig.ticks_ended() == 1


@pytest.mark.parametrize("policy", ["fail", "drop"])
def test_a_lost_network_fails_or_is_dropped_by_configuration(policy: str) -> None:
    rig = Rig(type1_fault=policy)
    ap = rig.join(AP, "ap", vehicles=(0,))
    net = rig.join(T1, "ns3")
    rig.begin_tick()
    rig.answer_ac(ap)
    assert net.owes1 == 0
    rig.lose(net, "connection broke")
    (fault,) = rig.machine.faults
    assert fault.peer == "ns3" and fault.fatal == (policy == "fail")
    if policy == "fail":
        assert rig.failure is not None and "'ns3'" in rig.failure
    else:
        assert rig.failure is None and rig.ticks_ended() == 1


def test_a_lost_autopilot_fails_the_run_naming_it_and_its_vehicles() -> None:
    rig = Rig(vehicles=2)
    rig.join(AP, "ap-a", vehicles=(0,))
    b = rig.join(AP, "ap-b", vehicles=(1,))
    rig.begin_tick()
    rig.lose(b)
    assert rig.failure is not None and "'ap-b'" in rig.failure and "vehicles [1]" in rig.failure


def test_joins_during_a_tick_are_admitted_when_it_ends() -> None:
    rig = Rig()
    ap = rig.join(AP, "ap", vehicles=(0,))
    rig.begin_tick()
    late = rig.join(T0, "late", vehicle=0)
    assert not late.state.admitted and rig.machine.subscribers() == [("ap", "AUTOPILOT")]
    rig.answer_ac(ap)
    assert late.state.admitted and late.owes0 is None
    rig.begin_tick()
    assert late.owes0 == TICK_NS


def test_a_vehicle_without_autopilot_waits_for_one_then_fails_after_the_join_limit() -> None:
    rig = Rig(vehicles=2)
    rig.join(AP, "ap", vehicles=(0,))
    rig.begin_tick()
    assert rig.machine.state.tick is TickState.AWAITING_HOLDERS and rig.watchdog.watching(JOIN)
    second = rig.join(AP, "ap-1", vehicles=(1,))  # admitted at once: the tick waits for it
    assert second.owes_ac and not rig.watchdog.watching(JOIN)
    rig2 = Rig(vehicles=2)
    rig2.join(AP, "ap", vehicles=(0,))
    rig2.begin_tick()
    assert rig2.stall() == [JOIN]
    assert rig2.failure is not None and "vehicles [1]" in rig2.failure


def test_deliver_goes_to_the_missions_of_its_vehicle_and_enqueue_outside_phase0_is_a_fault() -> None:
    rig = Rig(vehicles=2)
    ap = rig.join(AP, "ap", vehicles=(0, 1))
    m0 = rig.join(T0, "m0", vehicle=0)
    m1 = rig.join(T0, "m1", vehicle=1)
    net = rig.join(T1, "net")
    rig.begin_tick()
    rig.answer_ac(ap)
    rig.answer0(m0)
    rig.answer0(m1)
    pkt = p.Packet(0, 0, 1, 14550, 0, b"hi")
    rig.send(net, p.Deliver(1000, pkt))
    assert [type(msg) for msg in m1.inbox][-1] is p.Deliver and not isinstance(m0.inbox[-1], p.Deliver)
    rig.send(m0, p.Enqueue(pkt))
    assert m0.closed and rig.machine.faults[0].peer == "m0" and "outside its phase 0" in rig.machine.faults[0].reason


def test_upstream_back_in_time_or_refused_joins() -> None:
    rig = Rig()
    rig.join(AP, "ap", vehicles=(0,))
    with pytest.raises(Exception, match="already have an autopilot"):
        rig.join(AP, "ap2", vehicles=(0,))
    with pytest.raises(Exception, match="already has a clock owner"):
        rig.join(p.PeerKind.PHYSICS, "phys2")
    rig.tick = 5
    rig.begin_tick()
    rig.answer_ac(rig.peers[1])
    rig.tick = 2
    rig.begin_tick()
    assert rig.failure is not None and "back in time" in rig.failure


def test_a_child_obeys_its_parent_and_answers_for_its_subtree() -> None:
    clock = ManualClock()
    m = TickMachine(Watchdog(clock), stall_timeout_s=1.0)
    up = m.attach_upstream(0, p.PeerKind.CHILD, "parent")
    assert m.role is Role.CHILD
    ap = m.join(1, p.Hello(p.PROTOCOL_VERSION, AP, "ap", -1, (3,)))
    mission = m.join(2, p.Hello(p.PROTOCOL_VERSION, T0, "m3", 3))
    sent = _sent(m)
    (announce,) = [msg for pid, msg in sent if pid == up.pid][-1:]
    assert announce == p.Announce((3,), (3,), 2)
    m.from_upstream(p.BeginTick0(0, 0))  # the parent starts phase 0 first
    m.from_upstream(p.BeginTickAC(0, 0, 3, 1, (0.0, 0.0, 0.0)))
    sent = _sent(m)
    assert {(pid, type(msg)) for pid, msg in sent} == {(2, p.BeginTick0), (1, p.BeginTickAC)}
    m.receive(mission, p.EndTick0(0))
    m.receive(ap, p.EndTickAC(0, 3, (0.5,) * 4))
    assert [type(msg) for pid, msg in _sent(m) if pid == up.pid] == [p.EndTick0, p.EndTickAC]
    m.from_upstream(p.BeginTick1(0, 0, TICK_NS, (), ()))
    assert [type(msg) for pid, msg in _sent(m) if pid == up.pid] == [p.EndTick1]
    assert m.state.tick is TickState.IDLE and m.ticks_done == 1


def _sent(m: TickMachine) -> list[tuple[int, p.Message]]:
    out: list[tuple[int, p.Message]] = []
    for action in m.drain():
        if isinstance(action, Send):
            out += [(action.peer.pid, msg) for msg in p.FrameDecoder().feed(action.data)]
    return out


def test_watchdog_runs_on_the_injected_clock() -> None:
    clock = ManualClock(1_000)
    wd = Watchdog(clock)
    assert wd.timeout_s() is None and wd.expired() == []
    wd.watch(7, 2.0)
    wd.watch(3, 1.0)
    assert wd.timeout_s() == pytest.approx(1.0) and wd.next_deadline_ns() == 1_000 + 1_000_000_000
    clock.advance_to(1_000 + 1_500_000_000)
    assert wd.expired() == [3] and wd.timeout_s() == 0.0
    clock.advance_to(1_000 + 2_000_000_000)
    assert wd.expired() == [3, 7]
    wd.clear(3)
    wd.clear(7)
    assert wd.expired() == [] and not wd.watching(7)
    with pytest.raises(ValueError):
        clock.advance_to(0)


class _Tree:
    """A root machine (physics in-process) and one child machine below it, joined as the shells join them: the
    child's frames to its parent are held in one ordered stream (a TCP connection) that the test releases when
    it likes; the root's frames to the child are delivered at once."""

    def __init__(self) -> None:
        clock = ManualClock()
        self.root = TickMachine(Watchdog(clock), name="root", stall_timeout_s=1.0)
        self.root.attach_upstream(0, p.PeerKind.PHYSICS, "physics", PeerLink.IN_PROCESS)
        self.child = TickMachine(Watchdog(clock), name="child", stall_timeout_s=1.0)
        self.child.attach_upstream(0, p.PeerKind.CHILD, "parent")
        self.up: list[p.Message] = []
        """The child's frames on their way to the root, in order."""
        self.below: list[tuple[int, p.Message]] = []
        """What the child sent its own peers (pid, message)."""
        self.ticks_done: list[list[str]] = []
        """At each end of a root tick: the names of the missions the root knows have ended."""
        self.ap = self.child.join(1, p.Hello(p.PROTOCOL_VERSION, AP, "ap", -1, (0,)))
        self.mission = self.child.join(2, p.Hello(p.PROTOCOL_VERSION, T0, "m0", 0))
        self.pump()
        self.at_root = self.root.join(1, p.Hello(p.PROTOCOL_VERSION, p.PeerKind.CHILD, "child", -1, (0,)))
        self.release()

    def pump(self) -> None:
        for pid, msg in _sent(self.child):
            if pid == 0:
                self.up.append(msg)
            else:
                self.below.append((pid, msg))
        for action in self.root.drain():
            if isinstance(action, Send):
                for msg in p.FrameDecoder().feed(action.data):
                    self.child.from_upstream(msg)
                self.pump()
            elif isinstance(action, TickDone):
                self.ticks_done.append([e.peer for e in self.root.mission_exits])

    def release(self, n: int | None = None) -> None:
        """The next ``n`` of the child's frames reach the root (None: every frame, those it answers too)."""
        while self.up and (n is None or n > 0):
            self.root.receive(self.at_root, self.up.pop(0))
            self.pump()
            n = None if n is None else n - 1

    def sent_below(self, kind: type) -> list[p.Message]:
        out = [msg for _, msg in self.below if isinstance(msg, kind)]
        self.below = [(pid, msg) for pid, msg in self.below if not isinstance(msg, kind)]
        return out


def test_a_remote_missions_exit_ends_the_root_tick_it_left_in_whenever_its_frames_arrive() -> None:
    """A mission on a child channel answers its phase 0 with BYE: its child sends the exit up ahead of its own
    END-TICK-0 of that tick, so the root knows of it when that tick ends, however late the child's frames
    reach it, and the run ends at the same tick as on one machine. And the root's phase 0 begins only after
    the child's END-TICK-AC are in: the child decides its missions' phases from them (a MAVSDK mission on a
    cluster worker took part a phase late, and ended a phase late, when the BEGIN-TICK-0 came first)."""
    tree = _Tree()
    for tick in range(2):
        t = tick * TICK_NS
        tree.root.from_upstream(p.BeginTickAC(t, tick, 0, 1, (0.0, 0.0, 0.0)))
        tree.pump()
        assert tree.sent_below(p.BeginTickAC) and not tree.sent_below(p.BeginTick0)
        tree.child.receive(tree.ap, p.EndTickAC(t, 0, (0.5,) * 4))
        tree.pump()
        assert not tree.sent_below(p.BeginTick0)  # the answer is still on its way up
        tree.release()
        assert tree.sent_below(p.BeginTick0) == [p.BeginTick0(t, tick)]
        if tick == 0:
            tree.child.receive(tree.mission, p.EndTick0(t))
            tree.pump()
        else:
            tree.child.receive(tree.mission, p.Bye("script exited with 0", 0))
            tree.pump()
            assert [type(msg) for msg in tree.up] == [p.Announce, p.EndTick0]
            tree.release(1)  # the exit is in, the phase answer not yet: the tick goes on
            assert [e.peer for e in tree.root.mission_exits] == ["m0"] and len(tree.ticks_done) == 1
        tree.release()
        assert len(tree.ticks_done) == tick + 1
    assert tree.ticks_done == [[], ["m0"]]
    assert [e.exit_code for e in tree.root.mission_exits] == [0] and tree.root.missions_below() == 0
