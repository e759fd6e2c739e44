"""Acceptance: a dead, stalled, deaf or garbage-sending subscriber never hangs the run."""

from __future__ import annotations

import os
import re
import signal
import socket
import sys
import threading
import time

import pytest

from harness.channel import Channel, ChannelConfig
from harness.channel.drivers import run_fake_physics
from harness.core.errors import ScenarioError, SimulationError
from harness.wire import protocol as p
from harness.wire.client import ChannelClient, ChannelClosed
from tests.helpers import wait_until

from .conftest import SCRIPTS, Procs, load


def physics_in_thread(address: str, ticks: int, **kw: object) -> tuple[threading.Thread, dict[str, object]]:
    out: dict[str, object] = {}

    def run() -> None:
        try:
            out["stats"] = run_fake_physics(address, 1, ticks, **kw)  # type: ignore[arg-type]
        except Exception as exc:
            out["error"] = exc

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th, out


def test_kill_9_of_type0_is_reported_and_run_goes_on(procs: Procs) -> None:
    ch = Channel(ChannelConfig(stall_timeout_s=2)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        victim, _ = procs.driver("type0", ch.address, "--vehicle", "0", name="victim")
        _, survivor = procs.driver("type0", ch.address, "--vehicle", "0", name="survivor")
        wait_until(lambda: len(ch.subscribers()) == 3)
        th, out = physics_in_thread(ch.address, 3000, speed=10.0)  # 12 s of sim time in 1.2 s
        wait_until(lambda: ch.ticks_done > 200, what="200 ticks")
        killed_at = time.monotonic()
        os.kill(victim.pid, signal.SIGKILL)
        wait_until(lambda: ch.faults, timeout_s=2, what="the fault report")
        assert time.monotonic() - killed_at < 2.0  # within the watchdog limit
        th.join(30)
        assert "error" not in out and out["stats"].ticks == 3000  # type: ignore[attr-defined]
        (fault,) = ch.faults
        assert fault.peer == "victim" and fault.kind == "TYPE0" and not fault.fatal
        assert "disconnected" in fault.reason or "broke" in fault.reason
        assert any(e.peer == "victim" and e.exit_code == -1 for e in ch.mission_exits)
        # the survivor kept running to the end
        procs.wait_all()
        work = [ev for ev in load(survivor) if ev["ev"] == "work0"]
        assert work[-1]["tick"] == 2999
    finally:
        ch.stop()


def test_stalled_type0_is_dropped_after_the_limit(procs: Procs) -> None:
    ch = Channel(ChannelConfig(stall_timeout_s=0.5, phase_every=5)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        procs.driver("type0", ch.address, "--vehicle", "0", "--stall-at-tick", "50", name="sleepy")
        wait_until(lambda: len(ch.subscribers()) == 2)
        start = time.monotonic()
        stats = run_fake_physics(ch.address, 1, 200)
        assert stats.ticks == 200
        assert 0.5 <= time.monotonic() - start < 5
        (fault,) = ch.faults
        assert fault.peer == "sleepy" and "stalled" in fault.reason and "END-TICK-0 of tick 50" in fault.reason
    finally:
        ch.stop()


def test_type1_that_never_answers_fails_the_run_with_its_name(procs: Procs) -> None:
    ch = Channel(ChannelConfig(stall_timeout_s=1.0)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        procs.driver("type1", ch.address, "--never-answer", name="deaf-net")
        wait_until(lambda: len(ch.subscribers()) == 2)
        start = time.monotonic()
        with pytest.raises(ChannelClosed, match=r"deaf-net.*stalled"):
            run_fake_physics(ch.address, 1, 100)
        assert time.monotonic() - start < 3
        assert ch.wait(5) and ch.failure is not None and "deaf-net" in ch.failure
    finally:
        ch.stop()


def test_type1_fault_can_drop_instead(procs: Procs) -> None:
    ch = Channel(ChannelConfig(stall_timeout_s=0.5, type1_fault="drop")).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        procs.driver("type1", ch.address, "--never-answer", name="deaf-net")
        wait_until(lambda: len(ch.subscribers()) == 2)
        assert run_fake_physics(ch.address, 1, 100).ticks == 100
        assert [f.peer for f in ch.faults] == ["deaf-net"]
    finally:
        ch.stop()


@pytest.mark.parametrize("after_handshake", [False, True])
def test_garbage_sender_is_dropped(procs: Procs, after_handshake: bool) -> None:
    ch = Channel(ChannelConfig(stall_timeout_s=2)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        _, good = procs.driver("type0", ch.address, "--vehicle", "0", name="good")
        wait_until(lambda: len(ch.subscribers()) == 2)
        if after_handshake:
            client = ChannelClient.connect(ch.address, p.PeerKind.TYPE0, "garbler", vehicle=0)
            sock = client.sock
            wait_until(lambda: len(ch.subscribers()) == 3)
        else:
            host, port = ch.address.removeprefix("tcp://").rsplit(":", 1)
            sock = socket.create_connection((host, int(port)))
        th, out = physics_in_thread(ch.address, 500)
        sock.sendall(b"\x00\x00\x00\x10" + os.urandom(16) + b"\xff" * 64)
        th.join(20)
        assert "error" not in out, out
        wait_until(lambda: ch.faults, timeout_s=3)
        sock.close()
        procs.wait_all()
        fault = ch.faults[0]
        assert ("malformed" in fault.reason) or ("HELLO" in fault.reason)
        assert (fault.peer == "garbler") == after_handshake
        assert [ev["tick"] for ev in load(good) if ev["ev"] == "work0"][-1] == 499
    finally:
        ch.stop()


def test_late_joiner_is_admitted_between_ticks(procs: Procs) -> None:
    ch = Channel(ChannelConfig(stall_timeout_s=5, trace=True)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        wait_until(lambda: len(ch.subscribers()) == 1)
        th, out = physics_in_thread(ch.address, 2000, speed=5.0)
        assert "error" not in out
        wait_until(lambda: ch.ticks_done > 100)
        _, late = procs.driver("type0", ch.address, "--vehicle", "0", name="late")
        th.join(30)
        procs.wait_all()
        ticks = [ev["tick"] for ev in load(late) if ev["ev"] == "work0"]
        assert ticks and ticks[0] > 100
        assert ticks == list(range(ticks[0], 2000)), "from its first tick on, it took part in every phase 0"
    finally:
        ch.stop()


def test_missing_autopilot_fails_with_a_message() -> None:
    ch = Channel(ChannelConfig(join_timeout_s=0.5)).start()
    try:
        with pytest.raises(ChannelClosed, match=r"no autopilot joined for vehicles \[0\]"):
            run_fake_physics(ch.address, 1, 10)
    finally:
        ch.stop()


def test_secret_required_off_loopback_and_checked() -> None:
    with pytest.raises(ScenarioError, match="requires a shared secret"):
        ChannelConfig(address="tcp://0.0.0.0:0")
    ch = Channel(ChannelConfig(secret=b"s3cret")).start()
    try:
        with pytest.raises(SimulationError, match="did not prove the shared secret"):
            ChannelClient.connect(ch.address, p.PeerKind.TYPE0, "intruder", secret=b"wrong")
        with pytest.raises(SimulationError, match="did not prove the shared secret"):
            ChannelClient.connect(ch.address, p.PeerKind.TYPE0, "intruder")
        ok = ChannelClient.connect(ch.address, p.PeerKind.TYPE0, "friend", secret=b"s3cret")
        assert ok.welcome.peer_id > 0
        ok.close()
    finally:
        ch.stop()


def test_mission_that_leaves_while_packets_are_queued_for_it_exits_with_its_code() -> None:
    """A mission sends BYE and closes while DELIVERs for it are still unread: its socket resets, and the
    channel's next send to it fails. The channel must still read the BYE (exit code 0), not report the
    mission as dropped (seen once in a 10-vehicle run: 'connection broke while sending: Broken pipe')."""
    ch = Channel(ChannelConfig(phase_every=1, stall_timeout_s=5))
    ch.attach_physics()
    ch.attach_local_autopilots([0], lambda m: p.EndTickAC(m.t_ns, 0, (0.0, 0.0, 0.0, 0.0)))

    def network() -> None:
        with ChannelClient.connect(ch.address, p.PeerKind.TYPE1, "net") as c:
            while True:
                for msg in c.recv():
                    if isinstance(msg, p.BeginTick1):
                        pk = p.Packet(msg.t_ns, -1, 0, 1, 0, b"x" * 100)
                        c.send_many([p.Deliver(msg.t_ns, pk), p.Deliver(msg.t_ns, pk), p.EndTick1(msg.t_ns)])
                    elif isinstance(msg, p.Bye):
                        return

    def mission() -> None:
        c = ChannelClient.connect(ch.address, p.PeerKind.TYPE0, "leaver", vehicle=0)
        first = c.recv_one()
        assert isinstance(first, p.BeginTick0)
        c.send(p.EndTick0(first.t_ns))
        c.sock.recv(1, socket.MSG_PEEK)  # the DELIVERs of tick 0 have arrived; leave without reading them
        c.close("script exited with 0", 0)

    threads = [threading.Thread(target=f, daemon=True) for f in (network, mission)]
    for th in threads:
        th.start()
    try:
        assert ch.wait_for(lambda subs: len(subs) == 2, 10)
        ch.step([p.BeginTickAC(0, 0, 0, 1, (0.0, 0.0, 0.0), b"")])
        threads[1].join(5)
        time.sleep(0.05)  # the reset has reached the channel's socket
        for k in range(1, 4):
            ch.step([p.BeginTickAC(k * 4_000_000, k, 0, 1, (0.0, 0.0, 0.0), b"")])
        assert [(e.peer, e.exit_code) for e in ch.mission_exits] == [("leaver", 0)]
        assert ch.faults == []
    finally:
        ch.close()


@pytest.mark.parametrize(
    ("kind", "says"),
    [
        ("lock", "MainThread at {script}:11 in <module> (blocked in futex"),
        ("child", "child process {pid} ({python}) busy, in futex"),
    ],
)
def test_a_stuck_thread_or_child_is_named_with_the_call_it_is_in(procs: Procs, kind: str, says: str) -> None:
    """Issue 33: before the watchdog drops a mission that never goes idle, its log says where each busy thread and
    child process is, down to the system call (a lock's futex here), so the user knows what to change."""
    ch = Channel(ChannelConfig(stall_timeout_s=5, phase_every=5)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        mission = procs.mission(ch.address, "stuck.py", kind)
        wait_until(lambda: len(ch.subscribers()) == 2, what="mission joined")
        run_fake_physics(ch.address, 1, 100)  # returns once the channel has dropped the stalled mission (5 s)
        for pid in _descendants(mission.pid):  # the stuck child too: no orphans
            os.kill(pid, signal.SIGKILL)
        mission.kill()
        _, err = mission.communicate(timeout=60)
    finally:
        ch.stop()
    warning = next((line for line in err.splitlines() if "busy threads:" in line), "")
    pid = re.search(r"child process (\d+)", warning)
    expected = says.format(
        script=SCRIPTS / "stuck.py", pid=pid.group(1) if pid else "?", python=os.path.realpath(sys.executable)
    )
    assert expected in warning, err[-3000:]


def _descendants(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            children = [int(x) for x in f.read().split()]
    except OSError:
        return []
    return [d for c in children for d in [c, *_descendants(c)]]
