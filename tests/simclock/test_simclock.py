"""Acceptance: unmodified scripts on the sim clock, as real `harness mission` processes."""

from __future__ import annotations

import _thread
import asyncio
import datetime
import json
import queue
import socket
import threading
import time

import pytest

from harness.channel import Channel, ChannelConfig
from harness.channel.drivers import run_fake_physics
from harness.simclock import patch
from harness.simclock.runtime import SimRuntime
from harness.simclock.threads import HarnessThread, Role
from tests.helpers import wait_until

from .conftest import Procs

TICK_HZ = 250.0
PHASE_EVERY = 5
PHASE_PERIOD_S = PHASE_EVERY / TICK_HZ


def run_missions(
    procs: Procs, scripts: list[list[str]], sim_s: float, speed: float | None
) -> list[tuple[int, str, str]]:
    ch = Channel(ChannelConfig(stall_timeout_s=30, phase_every=PHASE_EVERY, tick_hz=TICK_HZ)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        missions = [procs.mission(ch.address, *s) for s in scripts]
        wait_until(lambda: len(ch.subscribers()) == 1 + len(scripts), what="missions joined")
        run_fake_physics(ch.address, 1, int(sim_s * TICK_HZ), tick_hz=TICK_HZ, speed=speed)
        out = []
        for m in missions:
            stdout, stderr = m.communicate(timeout=30)
            out.append((m.returncode, stdout, stderr))
        return out
    finally:
        ch.stop()


@pytest.mark.parametrize("speed", [0.5, 1.0, 50.0])
def test_sleep_takes_sim_time_at_any_speed(procs: Procs, speed: float) -> None:
    wall = time.monotonic()
    (code_s, out_s, err_s), (code_a, out_a, err_a) = run_missions(
        procs, [["sleep_sync.py"], ["sleep_async.py"]], sim_s=5.6, speed=speed
    )
    wall = time.monotonic() - wall
    assert code_s == 0, err_s
    assert code_a == 0, err_a
    sync, asy = json.loads(out_s), json.loads(out_a)
    for value in [*sync.values(), *asy.values()]:
        assert value == pytest.approx(5.0, abs=PHASE_PERIOD_S)
    # and the wall time followed the speed of the clock, not the script's 5 s
    assert wall >= 5.0 / speed * 0.9


def test_time_moves_only_with_ticks(procs: Procs) -> None:
    ((code, out, err),) = run_missions(procs, [["time_only_with_ticks.py"]], sim_s=1, speed=None)
    assert code == 0, err
    r = json.loads(out)
    assert r["during_work"] == 0.0
    assert r["after_sleep"] == pytest.approx(PHASE_PERIOD_S, abs=1e-6)  # woken at the next phase 0


def test_real_io_under_the_patched_loop(procs: Procs) -> None:
    ((code, out, err),) = run_missions(procs, [["udp_echo.py"]], sim_s=6, speed=None)
    assert code == 0, err
    r = json.loads(out)
    assert r["replies"] == [f"ping {i}" for i in range(20)]
    assert r["timed_out"] is True
    assert r["waited"] == pytest.approx(3.0, abs=PHASE_PERIOD_S)


def test_threads_new_loops_and_threading_waits(procs: Procs) -> None:
    ((code, out, err),) = run_missions(procs, [["threads_loop.py"]], sim_s=5, speed=None)
    assert code == 0, err
    r = json.loads(out)
    assert r["thread_sleep"] == pytest.approx(2.0, abs=PHASE_PERIOD_S)
    assert r["new_loop_sleep"] == pytest.approx(3.0, abs=PHASE_PERIOD_S)
    assert r["event_set"] is False and r["event_wait"] == pytest.approx(1.5, abs=PHASE_PERIOD_S)
    assert r["queue_timeout"] == pytest.approx(0.5, abs=PHASE_PERIOD_S)


def test_exit_codes_and_exceptions_are_reported(procs: Procs) -> None:
    start = time.monotonic()
    results = run_missions(procs, [["raises_with_thread.py"], ["exits_3.py"]], sim_s=1, speed=None)
    (code_r, _, err_r), (code_3, _, _) = results
    assert code_r == 1 and "mission failed on purpose" in err_r  # ended despite its stuck thread
    assert code_3 == 3
    assert time.monotonic() - start < 20


def test_patching_is_reversible_and_idempotent() -> None:
    originals = (time.time, time.monotonic, time.sleep, datetime.datetime, threading.Condition.wait)
    policy = asyncio.get_event_loop_policy()
    rt = SimRuntime(epoch_ns=1_700_000_000 * 10**9, phase_period_ns=20_000_000)
    patch.install(rt)
    patch.install(rt)
    try:
        assert time.time() == 1_700_000_000.0 and time.monotonic() == 0.0 and time.perf_counter_ns() == 0
        assert datetime.datetime.now().timestamp() == 1_700_000_000.0
        assert "time.sleep" in patch.patched_names() and "threading._time" in patch.patched_names()
        loop = asyncio.new_event_loop()
        assert loop.time() == 0.0
        loop.close()
        # threads of the harness itself (and anything before the first phase) keep real waits
        q: queue.Queue[int] = queue.Queue()
        with pytest.raises(queue.Empty):
            q.get(timeout=0.01)
    finally:
        patch.uninstall()
        patch.uninstall()
    assert (time.time, time.monotonic, time.sleep, datetime.datetime, threading.Condition.wait) == originals
    assert asyncio.get_event_loop_policy() is policy
    assert abs(time.time() - datetime.datetime.now().timestamp()) < 1


def _phases_of(ch: Channel, name_part: str) -> int:
    return sum(1 for _, event, _, peer in ch.trace if event == "et0" and name_part in peer)


def test_lookahead_skips_idle_phases_and_every_wait_still_ends_on_time(procs: Procs) -> None:
    """A mission tells the channel its next timed wait (END-TICK-0 ``idle_until_ns``): it is left out of the
    phases in between, and its sleeps still end at the same phase as without lookahead."""
    ch = Channel(ChannelConfig(stall_timeout_s=30, phase_every=PHASE_EVERY, tick_hz=TICK_HZ, trace=True)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        mission = procs.mission(ch.address, "sleep_steps.py")
        procs.driver("type0", ch.address, "--vehicle", "0", name="every-phase")
        wait_until(lambda: len(ch.subscribers()) == 3, what="subscribers joined")
        ticks = int(3.0 * TICK_HZ)
        run_fake_physics(ch.address, 1, ticks, tick_hz=TICK_HZ)
        stdout, stderr = mission.communicate(timeout=30)
        assert mission.returncode == 0, stderr
        assert json.loads(stdout) == pytest.approx([0.5, 1.0, 1.5, 2.0], abs=PHASE_PERIOD_S)
        phase_ticks = ticks // PHASE_EVERY
        assert _phases_of(ch, "every-phase") == phase_ticks  # a subscriber without lookahead: every phase
        assert _phases_of(ch, "sleep_steps") <= 8  # first phase, four wake-ups, the exit: not 150
    finally:
        ch.stop()


def test_wall_clock_io_wakes_a_mission_left_out_by_its_lookahead(procs: Procs) -> None:
    """A script waiting on a socket with no timeout has no deadline: the channel leaves it out of phase 0
    until the datagram arrives (on the wall clock) and the mission's WAKE brings it back."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    ch = Channel(ChannelConfig(stall_timeout_s=30, phase_every=PHASE_EVERY, tick_hz=TICK_HZ, trace=True)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0")
        mission = procs.mission(ch.address, "wait_datagram.py", str(port))
        wait_until(lambda: len(ch.subscribers()) == 2, what="subscribers joined")
        physics = threading.Thread(
            target=run_fake_physics, args=(ch.address, 1, int(4.0 * TICK_HZ)), kwargs={"speed": 2.0}, daemon=True
        )
        physics.start()
        wait_until(lambda: ch.ticks_done >= int(1.0 * TICK_HZ), what="1 s of sim time")
        idle_phases = _phases_of(ch, "wait_datagram")
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b"hello", ("127.0.0.1", port))
        sent_at_s = ch.ticks_done / TICK_HZ
        stdout, stderr = mission.communicate(timeout=30)
        physics.join(30)
        assert mission.returncode == 0, stderr
        r = json.loads(stdout)
        assert r["payload"] == "hello"
        assert sent_at_s <= r["at_s"] < sent_at_s + 0.2  # handled within a few phases of its arrival
        assert idle_phases <= 3  # while it waited, it was left out (1 s = 50 phases)
    finally:
        ch.stop()


def test_a_thread_waiting_for_the_gate_is_never_counted_idle_without_being_queued_on_it() -> None:
    """The script's main thread waits for the first phase 0 (``wait_first_phase``), and a thread whose I/O came
    between phases waits for the next one. It used to be counted idle first and queued on the gate a moment
    later: a phase 0 that opened and found every thread idle in that moment ended without it, and a MAVSDK
    script started a phase late (its threads made at t=0.02 s instead of 0, about 1 run in 30 under load).
    Here the clock thread runs exactly in that moment: phase 0 opens, and ends if the waiter counts idle."""
    rt = SimRuntime(epoch_ns=0, phase_period_ns=20_000_000)
    ended_without_it: list[bool] = []

    def clock_thread_runs_now() -> None:
        with rt._mu:
            rt._open_gate_locked()
            if rt.threads.blocked:  # the waiter counts idle: this phase 0 is over
                rt._gate_open = False
                ended_without_it.append(True)

    rt._poke = clock_thread_runs_now  # type: ignore[method-assign]
    waiter = threading.Thread(target=rt.wait_first_phase, daemon=True)
    waiter.start()
    waiter.join(2.0)
    assert not waiter.is_alive() and not ended_without_it, "the phase ended without the thread waiting for it"
    rt._gate_open = True
    rt.wait_gate()  # phase 0 is on: no wait at all


def test_a_join_counts_idle_only_while_the_joined_thread_still_runs_python() -> None:
    """``Thread.join`` ends when the joined thread's OS thread ends, after its Python part is over: counted idle
    then, the phase closed and the join returned between phases, on the wall clock (asyncio.run's executor shutdown
    ended a MAVSDK script one or two phases late in some runs). The join registers a ``JOIN`` blocker: idle while
    the joined thread is registered, busy from its end until the join returns."""
    rt = SimRuntime(epoch_ns=0, phase_period_ns=20_000_000)
    patch.install(rt)
    hold = _thread.allocate_lock()
    hold.acquire()
    try:
        rt._started = rt._gate_open = True  # in phase 0: waits of script threads are sim-time waits
        joined = threading.Thread(target=hold.acquire, daemon=True)  # blocks in C: busy for the registry
        joined.start()
        joiner = threading.Thread(target=joined.join, daemon=True)
        joiner.start()
        wait_until(lambda: joiner.ident in rt.threads.blocked, timeout_s=5.0, what="the joiner waits in join")
        with rt._mu:
            busy = [e.thread for e in rt.threads.busy(())]
            assert joined in busy and joiner not in busy, "joining a running thread is idle"
            assert rt.threads.waits(joiner.ident or 0, ()) == "join"
            rt.threads.end(joined.ident or 0)  # the joined thread's Python part is over, its OS thread not yet
            assert rt.threads.waits(joiner.ident or 0, ()) is None, "a join of an ended thread is busy"
        hold.release()
        joiner.join(5.0)
        assert not joiner.is_alive()
        with rt._mu:
            assert joiner.ident not in rt.threads.blocked
            assert [e.thread for e in rt.threads.busy(())] == [threading.main_thread()]  # this test runs
    finally:
        patch.uninstall()


def test_threads_are_registered_when_they_start_with_the_role_their_code_gives_them() -> None:
    """The registry, not a scan of ``threading.enumerate()``: a thread counts from ``Thread.start`` (busy while it
    is being started), ends with its Python part; the harness's own threads and threads a C library made never
    count, and their waits stay on the wall clock."""
    rt = SimRuntime(epoch_ns=0, phase_period_ns=20_000_000)
    patch.install(rt)
    hold = _thread.allocate_lock()
    hold.acquire()
    seen: dict[str, object] = {}
    try:
        rt._started = rt._gate_open = True
        script = threading.Thread(target=hold.acquire, daemon=True)
        script.start()
        harness_own = HarnessThread(target=lambda: seen.update(harness=rt.on_sim_time()))
        harness_own.start()
        harness_own.join(5.0)
        done = _thread.allocate_lock()
        done.acquire()

        def foreign() -> None:  # made by C, as MAVSDK's threads are: never registered
            seen["foreign"] = rt.on_sim_time()
            done.release()

        _thread.start_new_thread(foreign, ())
        assert done.acquire(True, 5.0)
        with rt._mu:
            assert rt.threads.role(script.ident or 0) is Role.SCRIPT
            assert [e.thread for e in rt.threads.busy(())] == [threading.main_thread(), script]
        assert seen == {"harness": False, "foreign": False}
        hold.release()
        script.join(5.0)
        with rt._mu:
            assert script.ident not in rt.threads.threads
            assert [e.thread for e in rt.threads.busy(())] == [threading.main_thread()]
    finally:
        patch.uninstall()


def test_a_pool_starts_a_thread_for_work_no_waiting_worker_can_take() -> None:
    """A pool's hand-off in a mission (``patch._PoolQueue``, ``patch._IdleWorkers``): ``submit`` starts no new
    thread only when a worker waits in ``get`` for every queued item. CPython's idle semaphore is released after
    every item, also by a worker that goes straight on to a queued one: it then said "idle" for a busy worker,
    and a blocking call queued behind another (a swarm script's seventh MAVSDK ``first_autopilot`` waited a
    phase for a free thread in some runs only)."""
    work = patch._PoolQueue()
    idle = patch._IdleWorkers(work)
    idle.release()
    idle.release()  # two items done: CPython's semaphore would now say two workers are free
    work.put("first")
    assert not idle.acquire(timeout=0), "an item is queued and no worker waits: the pool must start a thread"
    got: list[object] = []

    def worker() -> None:
        got.append(work.get())

    first = threading.Thread(target=worker, daemon=True)
    first.start()
    first.join(5.0)
    assert got == ["first"] and work.waiting == 0, "a worker that found an item never counted as waiting"
    second = threading.Thread(target=worker, daemon=True)
    second.start()
    wait_until(lambda: work.waiting == 1, timeout_s=5.0, what="the worker waits in get")
    work.put("second")
    assert idle.acquire(timeout=0), "a worker waits for the one queued item: no new thread"
    second.join(5.0)
    assert got == ["first", "second"]
    work.put("third")
    work.put("fourth")
    assert not idle.acquire(timeout=0)


def test_a_pool_made_without_a_size_has_the_same_size_on_every_machine() -> None:
    rt = SimRuntime(epoch_ns=0, phase_period_ns=20_000_000)
    patch.install(rt)
    try:
        from concurrent.futures import ThreadPoolExecutor

        pool = ThreadPoolExecutor()
        assert pool._max_workers == patch.DEFAULT_POOL_WORKERS
        assert ThreadPoolExecutor(max_workers=3)._max_workers == 3
        assert pool.submit(lambda: 7).result(timeout=5) == 7  # before the first phase: waits are the wall clock's
        pool.shutdown()
    finally:
        patch.uninstall()
