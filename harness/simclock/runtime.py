"""Sim time inside a mission process: sim-time waits, the phase-0 gate and idle detection.

A mission process runs only during phase 0 of the ticks. The *clock thread* (see ``mission.py``) calls
:meth:`SimRuntime.run_phase` on every BEGIN-TICK-0: it advances sim time, wakes every wait that is
due, opens the *gate*, waits until the script is idle, closes the gate and returns (then END-TICK-0
goes out). The script is idle when every one of its threads is

- in a sim-time wait (patched ``time.sleep``, ``Condition.wait`` and everything built on it:
  ``Event.wait``, ``Queue.get``, ``Future.result``…), or
- an event loop with nothing ready, blocked in its selector (``SimSelector``), or
- parked in a known idle place of the standard library (a thread-pool worker waiting for work,
  ``Thread.join``).

A thread is woken only while the gate is open, and whoever wakes it marks it busy first, under the
runtime's lock: the decision "all idle" and every wake-up are serialised, so no script code ever runs
outside phase 0, whatever arrives on the wall clock (sockets, MAVSDK's C++ threads) in between.

Internal waits here use raw ``_thread`` locks, never ``threading.Condition``, because that is patched.
"""

from __future__ import annotations

import _thread
import collections
import logging
import os
import select
import signal
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from types import FrameType
from typing import TextIO

from harness.core.clock import NS_PER_S, WALL, Clock
from harness.simclock.native import NO_DEADLINE as NATIVE_NO_DEADLINE
from harness.simclock.native import NativeClock
from harness.wire.protocol import EVERY_PHASE, NO_DEADLINE

log = logging.getLogger(__name__)

_LockType = type(_thread.allocate_lock())
_real_select = select.select  # captured before ``patch`` makes select.select a sim-time wait
_REPORT_AFTER_NS = 3 * NS_PER_S

INFRA_THREAD_PREFIX = "harness-"
"""Threads whose name starts with this belong to the harness, not to the script."""

_JOIN_FRAME = ("threading.py", "_wait_for_tstate_lock")
"""Thread.join: idle while the joined thread still runs Python (what ends the join is that thread's end, in a
phase); busy once the joined thread has left ``threading.enumerate()``: its OS thread ends on the wall clock, and
the join returns then — in this phase, not in whichever phase the machine's pace gives it."""
_IDLE_FRAMES: set[tuple[str, str]] = {_JOIN_FRAME}
ZENO_READS = 1000
"""A script thread that reads the clock this many times in one phase without waiting waits for the next phase
(``clock_read``): a loop that polls ``time.time()`` without sleeping sees time pass, as on a real vehicle,
instead of stopping the simulation."""


@dataclass(eq=False)
class Waiter:
    """One blocked thread: released by a notify, a due deadline, or a loop wake-up."""

    ident: int
    lock: _thread.LockType
    deadline_ns: int | None = None
    wake: Callable[[], None] | None = None
    """For event loops: how to wake it (write to its self-pipe) instead of releasing ``lock``."""
    released: bool = False
    timed_out: bool = False
    interrupted: bool = False
    """Released because a signal timer fired for its thread (``signal.setitimer``): a sleep goes on after the
    handler, as Python's does (PEP 475)."""
    rfds: tuple[int, ...] = ()
    wfds: tuple[int, ...] = ()
    """For I/O waits (``iowait``): the descriptors it waits for, polled when MAVLink settles."""
    every_phase: bool = False
    """It waits for its vehicle's MAVLink, which arrives at every phase: no lookahead past this phase."""


@dataclass
class Delivery:
    at_ns: int
    src: int
    dst: int
    port: int
    payload: bytes
    rssi_dbm: float


@dataclass
class _Outgoing:
    dst: int
    port: int
    payload: bytes


@dataclass
class PhaseStats:
    phases: int = 0
    last_phase_wall_ns: int = 0
    busy_wall_ns: int = 0
    waits_released: int = 0
    outbox: list[_Outgoing] = field(default_factory=list)


class SimRuntime:
    """The sim clock of one mission process. All times are integer nanoseconds."""

    def __init__(self, epoch_ns: int, phase_period_ns: int, vehicle: int = -1, wall: Clock = WALL) -> None:
        self.wall = wall
        """Real time: phase statistics, and the sleeps of threads that are not the script's."""
        self.epoch_ns = epoch_ns
        self.phase_period_ns = phase_period_ns
        self.vehicle = vehicle
        self._now_ns = 0
        self._timers_open_ns = -1
        self._started = False
        self._mu = _thread.allocate_lock()
        self._signal = _thread.allocate_lock()
        self._signal.acquire()
        self._gate_open = False
        self._idle: dict[int, Waiter] = {}
        self._timed: list[Waiter] = []
        self._gate_waiters: list[Waiter] = []
        self._by_lock: dict[int, Waiter] = {}
        self._done_threads: set[int] = set()
        self._script_threads: dict[int, bool] = {}
        self.stats = PhaseStats()
        self.inbox: collections.deque[Delivery] = collections.deque()
        self._inbox_waiters: list[Waiter] = []
        self._inbox_callbacks: dict[int, Callable[[], None]] = {}
        self._next_token = 0
        self.closed = False
        self.request_phase: Callable[[], None] | None = None
        """Called (once between two phases) when script work became ready outside phase 0 on the wall
        clock: the mission runner sends WAKE, so that a channel using lookahead includes it again."""
        self._wake_requested = False
        self._in_phase = False
        """Between the start of a phase 0 and its end: a thread queued on the gate meanwhile runs in it (no WAKE)."""
        self._reads: dict[int, int] = {}
        self.mavlink_fds: set[int] = set()
        """Descriptors of the script's sockets to its vehicle (``simsocket``)."""
        self.mavlink_sent = 0
        """Datagrams the script sent its vehicle (``simsocket``); phase 0 ends only once they are handled."""
        self._mavlink_synced = 0
        self.settle_mavlink: Callable[[], bool] | None = None
        """Waits (wall clock) until the vehicle has handled everything sent to it; False: it did not answer."""
        self.trace: TextIO | None = None
        """Where every phase 0 that ends is written, with why each thread counted idle (diagnostics)."""
        self.native: NativeClock | None = None
        self.itimer: tuple[int, int] | None = None
        """``signal.setitimer(ITIMER_REAL, …)`` on sim time: (deadline, interval) in ns; SIGALRM at that phase."""
        """The C threads of a library on the sim clock (MAVSDK's core, ``native.attach``): they take part in the
        idle decision, and what they send the vehicle is settled like the script's own MAVLink."""

    # -- reading the clock (any thread) --------------------------------------------------------

    def now_ns(self) -> int:
        return self._now_ns

    def unix_ns(self) -> int:
        return self.epoch_ns + self._now_ns

    def timers_held(self) -> bool:
        """Whether event loops' timers that are due now wait: until the phase's second round (see :meth:`run_phase`),
        when the timed waits fall due, as a ``time.sleep`` does.

        A loop woken in the first round (a MAVSDK callback's ``call_soon_threadsafe``) would otherwise run its due
        timers at once, while other threads still deliver this tick's telemetry: a swarm script's 10 Hz control
        task read some vehicles' positions of this tick and some of the last, depending on the machine's pace."""
        return self._started and self._timers_open_ns != self._now_ns

    # -- the clock thread ----------------------------------------------------------------------

    def run_phase(self, t_ns: int, idle_poll_s: float = 0.001) -> tuple[int, bool, bool]:
        """One phase 0 at sim time ``t_ns``: wake what is due, run until idle. Clock thread only.

        Wake-ups come in rounds, each run until everything is idle: first MAVSDK's own threads (``native``)
        absorb what came in, with every script thread held (:meth:`_library_first`); then the script threads
        whose I/O or notification arrived since the last phase (a reader thread handles the telemetry of this
        tick); then the timed waits that fall due, event loops' timers among them (a thread polling with
        ``time.sleep`` sees what the reader stored; :meth:`timers_held`). So the order of the rounds is the same
        at any pace, not the order in which the threads happen to run.

        Returns the lookahead for END-TICK-0: the earliest deadline of a timed wait (``NO_DEADLINE`` when
        there is none), whether a delivered packet would wake a waiting thread and whether the vehicle's MAVLink
        would (:meth:`_lookahead_locked`).
        """
        now_wall = self.wall.now_ns
        start = now_wall()
        with self._mu:
            if t_ns < self._now_ns:
                raise ValueError(f"sim time went backwards: {t_ns} < {self._now_ns}")
            self._now_ns = t_ns
            self._started = True
            self._in_phase = True
            self._reads.clear()
        native = self.native
        if native is not None:
            native.begin(t_ns)
            self._library_first(native)
        with self._mu:
            self._open_gate_locked()
        # A thread whose socket received data before this phase may not have run yet to notice (a loaded
        # machine schedules it late): its wait is still counted idle, so look at the sockets themselves.
        self._release_ready_io()
        report_at = start + _REPORT_AFTER_NS
        while True:
            generation = native.generation() if native is not None else 0
            settle = False
            with self._mu:
                if self._all_idle_locked():
                    if self._sent_locked() != self._mavlink_synced and self.settle_mavlink is not None:
                        settle = True
                    elif native is None or native.try_close(generation):
                        # The library's threads wait with nothing ready, and its gate is shut: what they handed
                        # the script before they went idle (a callback's call_soon_threadsafe) is in a socket now.
                        released = self._release_ready_io_locked()
                        if not released:
                            self._timers_open_ns = t_ns  # the second round: event loops' timers fall due too
                            released = self._release_due_locked(t_ns)
                        if released:
                            if native is not None:
                                native.reopen()
                            continue
                        self._gate_open = False  # the decision "idle" and closing the gate are one step
                        self._in_phase = False
                        self._wake_requested = False
                        lookahead = self._lookahead_locked()
                        if self.trace is not None:
                            self._trace_close_locked(t_ns)
                        break
            if settle:
                self._settle()
                continue
            if native is not None:
                native.wait_change(generation, round(idle_poll_s * NS_PER_S))
            else:
                self._signal.acquire(True, idle_poll_s)
            report_at = self._warn_if_slow(start, report_at, "the script")
        self.stats.phases += 1
        self.stats.last_phase_wall_ns = now_wall() - start
        self.stats.busy_wall_ns += self.stats.last_phase_wall_ns
        return lookahead

    def _sent_locked(self) -> int:
        """MAVLink sent to the vehicle so far: by the script's sockets and by the library on the sim clock."""
        return self.mavlink_sent + (self.native.sent() if self.native is not None else 0)

    def _release_due_locked(self, t_ns: int) -> bool:
        """Second round: the timed waits that fell due, once the I/O of this tick is handled."""
        if self.itimer is not None and self.itimer[0] <= t_ns:
            self._fire_itimer_locked(t_ns)
            return True
        due = [w for w in self._timed if not w.released and w.deadline_ns is not None and w.deadline_ns <= t_ns]
        for w in due:
            w.timed_out = True
            self._release_locked(w)
        self.stats.waits_released += len(due)
        return bool(due)

    def set_itimer(self, delay_ns: int, interval_ns: int) -> tuple[int, int]:
        """Arm (``delay_ns`` > 0) or disarm the process's real-time signal timer on sim time; returns what was left of
        the old one (delay, interval), as ``setitimer`` does."""
        with self._mu:
            old = self._get_itimer_locked()
            self.itimer = (self._now_ns + delay_ns, max(0, interval_ns)) if delay_ns > 0 else None
        self._poke()
        return old

    def get_itimer(self) -> tuple[int, int]:
        """What is left of the signal timer (delay, interval) in ns; (0, 0) when it is not armed."""
        with self._mu:
            return self._get_itimer_locked()

    def _get_itimer_locked(self) -> tuple[int, int]:
        if self.itimer is None:
            return 0, 0
        deadline, interval = self.itimer
        return max(1, deadline - self._now_ns), interval

    def _fire_itimer_locked(self, t_ns: int) -> None:
        """The signal timer fell due (the phase's second round): SIGALRM goes to the main thread, which runs its handler
        in this phase: it is marked busy first and its wait, Python's or C's, ends (a sleep goes on afterwards)."""
        assert self.itimer is not None
        deadline, interval = self.itimer
        self.itimer = (max(deadline + interval, t_ns + 1), interval) if interval > 0 else None
        main = threading.main_thread().ident
        assert main is not None
        w = self._idle.get(main)
        if w is not None and not w.released:
            w.interrupted = True
            w.released = True  # busy from now on: the handler runs in this phase
            self._idle.pop(main, None)
        signal.pthread_kill(main, signal.SIGALRM)
        if w is not None:
            if w.wake is not None:
                w.wake()
            else:
                self._unlock(w)
        elif self.native is not None:
            self.native.interrupt(main)

    def _settle(self) -> None:
        """The script is idle but sent its vehicle MAVLink in this phase: wait (wall clock) until the vehicle
        has handled it (``settle_mavlink``), then let every thread whose socket now holds an answer run.

        So a command and its answer take no sim time, and a command takes effect before the next tick,
        whatever the machine's pace (a MAVSDK request is held the same way, in ``mavsdk_compat``)."""
        native = self.native
        with self._mu:
            sent = self._sent_locked()
            # Nothing runs while the vehicle answers: what it sends before its echo is read after it, so one round
            # (the script's messages up to this settle, and their answers) never runs into the next, at any pace.
            self._gate_open = False
            if native is not None:
                native.pause()
        settle = self.settle_mavlink
        try:
            if settle is not None and not settle():
                log.warning("the vehicle did not confirm the script's MAVLink in time; going on without its answer")
        finally:
            with self._mu:
                self._mavlink_synced = sent
            if native is not None:
                native.reopen()
                self._library_first(native)
            with self._mu:
                self._open_gate_locked()
        self._release_ready_io()

    def _library_first(self, native: NativeClock) -> None:
        """Let MAVSDK's threads absorb what came in (a tick's telemetry, the answers to a settle) before any script
        code runs: wait (wall clock) until they are idle with nothing ready, with the script's gate shut. What they
        hand the script (callbacks, the results of blocking calls) is then all there when it runs, in an order
        that does not depend on the machine's pace (a script resumed by one vehicle's answer read another's
        position of this tick in some runs and of the last in others)."""
        start = self.wall.now_ns()
        report_at = start + _REPORT_AFTER_NS
        while True:
            generation = native.generation()
            if native.wait_idle(10_000_000):  # in C, without the GIL, until the library's threads are idle
                with self._mu:
                    if self._all_idle_locked() and not native.release_ready():
                        return
                native.wait_change(generation, 1_000_000)  # a script thread the library woke: until it waits
            report_at = self._warn_if_slow(start, report_at, "MAVSDK's threads to take in this tick")

    def _warn_if_slow(self, start: int, report_at: int, waiting_for: str) -> int:
        """Every ``_REPORT_AFTER_NS`` of wall time that phase 0 waits (since ``start``), one warning naming the busy
        threads, so a stalled mission explains itself before the watchdog drops it. Returns the next report time."""
        now = self.wall.now_ns()
        if now <= report_at:
            return report_at
        log.warning(
            "phase 0 at t=%.3f s has waited %.1f s for %s; busy threads: %s",
            self._now_ns / NS_PER_S,
            (now - start) / NS_PER_S,
            waiting_for,
            "; ".join(self.busy_threads()) or "none",
        )
        return report_at + _REPORT_AFTER_NS

    def _open_gate_locked(self) -> None:
        """Script threads may run again: those that were woken while the gate was shut run now."""
        self._gate_open = True
        gated, self._gate_waiters = self._gate_waiters, []
        for w in gated:
            self._release_locked(w)
        self.stats.waits_released += len(gated)

    def _release_ready_io(self) -> None:
        """Let every thread waiting on a descriptor that is ready now run (clock thread, phase 0).

        Whether a thread runs in this phase then depends on what is in its sockets, not on when the machine
        happened to schedule it after the data arrived."""
        with self._mu:
            self._release_ready_io_locked()

    def _release_ready_io_locked(self) -> bool:
        released = False
        for w in [w for w in self._idle.values() if (w.rfds or w.wfds) and not w.released]:
            try:
                r, wr, _ = _real_select(w.rfds, w.wfds, [], 0)
            except (OSError, ValueError):
                r = wr = [0]
            if r or wr:
                self._release_locked(w)
                released = True
        return released

    def _lookahead_locked(self) -> tuple[int, bool, bool]:
        """(earliest deadline, DELIVERs wake, the vehicle's MAVLink wakes) for END-TICK-0.

        MAVSDK's threads wait for their sockets: what the vehicle sends them wakes them. A mission of one vehicle
        then says so (``mavlink_wakes``) and the channel wakes it at the phases after which its vehicle sent it
        MAVLink (most phases bring none: telemetry comes at 10 Hz or less, phases at 50 Hz); a swarm mission
        (several vehicles, no ``vehicle``) takes part in every phase."""
        native = self.native
        if self._gate_waiters or any(w.every_phase for w in self._idle.values()):
            return EVERY_PHASE, True, False
        mavlink_wakes = native is not None and native.waits_for_io()
        if mavlink_wakes and self.vehicle < 0:
            return EVERY_PHASE, True, False
        deadlines = [w.deadline_ns for w in self._timed if not w.released and w.deadline_ns is not None]
        if self.itimer is not None:
            deadlines.append(self.itimer[0])
        if native is not None and (d := native.next_deadline_ns()) != NATIVE_NO_DEADLINE:
            deadlines.append(d)
        return (
            min(deadlines, default=NO_DEADLINE),
            bool(self._inbox_waiters or self._inbox_callbacks),
            mavlink_wakes,
        )

    def _trace_close_locked(self, t_ns: int) -> None:
        """One line per phase 0 that ended: why each thread counted idle (``HARNESS_SIMTIME_TRACE_DIR``)."""
        why = []
        for t in threading.enumerate():
            ident = t.ident
            if t.name.startswith(INFRA_THREAD_PREFIX) or ident is None:
                continue
            if ident in self._done_threads:
                state = "done"
            elif ident in self._idle:
                state = "waits"
            elif self.native is not None and self.native.thread_waiting(ident):
                state = "in-mavsdk"
            elif isinstance(t, threading._DummyThread) or not self._is_script_thread(t):
                state = "outside"
            else:
                frame = sys._current_frames().get(ident)
                state = f"at {frame.f_code.co_name}" if frame is not None else "ended"
            why.append(f"{t.name}={state}")
        assert self.trace is not None
        self.trace.write(f"{t_ns} close {' '.join(why)}\n")
        self.trace.flush()

    def busy_threads(self) -> list[str]:
        """Where every thread and child process that keeps phase 0 from ending is, and which call it is in
        (diagnostics: the warning before the watchdog drops the mission)."""
        with self._mu:
            native = [self.native.describe()] if self.native and self.native.busy() else []
            return native + [f"{t.name} at {where}{_in_kernel(t)}" for t, where in self._busy_locked()]

    def take_outbox(self) -> list[_Outgoing]:
        with self._mu:
            out, self.stats.outbox = self.stats.outbox, []
        return out

    def deliver(self, ds: list[Delivery]) -> None:
        """Packets from the network (clock thread, between phases): wake ``receive`` waiters.

        No WAKE is needed: the channel itself includes a mission that waits on its inbox in the next
        phase 0 when it routes a DELIVER to it (``deliver_wakes`` of END-TICK-0).
        """
        with self._mu:
            self.inbox.extend(ds)
            waiters, self._inbox_waiters = self._inbox_waiters, []
            for w in waiters:
                self._release_locked(w, wake=False)
            callbacks = list(self._inbox_callbacks.values())
        for cb in callbacks:
            cb()

    def add_inbox_callback(self, cb: Callable[[], None]) -> int:
        """Call ``cb`` (on the clock thread) when a packet is delivered; counts as waiting on the inbox.
        Returns a token for :meth:`remove_inbox_callback` (``receive_async`` wakes its event loop this way)."""
        with self._mu:
            self._next_token += 1
            self._inbox_callbacks[self._next_token] = cb
            return self._next_token

    def remove_inbox_callback(self, token: int) -> None:
        with self._mu:
            self._inbox_callbacks.pop(token, None)

    def close(self) -> None:
        """The run is over: release every wait so nothing blocks forever."""
        if self.native is not None:
            self.native.close()
        with self._mu:
            self.closed = True
            self._gate_open = True
            for w in list(self._idle.values()) + self._gate_waiters + self._timed:
                if not w.released:
                    w.timed_out = True
                    self._release_locked(w)

    # -- script threads ------------------------------------------------------------------------

    def clock_read(self) -> None:
        """A script thread read the clock. The ``ZENO_READS``-th read in one phase without a wait in between
        waits until the next phase (a busy-wait on ``time.time()`` would otherwise hold phase 0 forever)."""
        if not self._started:
            return
        ident = _thread.get_ident()
        n = self._reads.get(ident, 0) + 1
        if n < ZENO_READS:
            self._reads[ident] = n
            return
        self._reads.pop(ident, None)
        if self._tracked():
            self.sleep_ns(1)

    def sleep_ns(self, ns: int) -> None:
        """Block the calling thread for ``ns`` of sim time (at least until a later phase 0)."""
        if not self._tracked():
            self.wall.sleep_ns(ns)
            return
        deadline = self._now_ns + ns
        while self._now_ns < deadline and not self.closed:
            w = self.new_waiter(deadline_ns=deadline)
            try:
                w.lock.acquire()  # a signal handler that raises (a timer's) leaves through here
            finally:
                self.finish_wait(w)
            if not w.interrupted:
                return

    def new_waiter(
        self,
        deadline_ns: int | None = None,
        lock: _thread.LockType | None = None,
        wake: Callable[[], None] | None = None,
        inbox: bool = False,
        rfds: tuple[int, ...] = (),
        wfds: tuple[int, ...] = (),
        every_phase: bool = False,
    ) -> Waiter:
        """Register the calling thread as idle until released; the caller then blocks on ``lock``.

        With ``wake`` (event loops) the runtime calls ``wake()`` instead of releasing a lock.
        """
        if lock is None:
            lock = _thread.allocate_lock()
            lock.acquire()
        w = Waiter(_thread.get_ident(), lock, deadline_ns, wake, rfds=rfds, wfds=wfds, every_phase=every_phase)
        self._reads.pop(w.ident, None)
        with self._mu:
            if self.closed:
                w.released = w.timed_out = True
                self._unlock(w)
                return w
            self._idle[w.ident] = w
            self._by_lock[id(lock)] = w
            if deadline_ns is not None:
                self._timed.append(w)
            if inbox:
                self._inbox_waiters.append(w)
        self._poke()
        return w

    def release(self, lock: _thread.LockType) -> bool:
        """Wake the thread blocked on ``lock`` (a Condition's waiter). False if not ours."""
        with self._mu:
            w = self._by_lock.get(id(lock))
            if w is None or w.lock is not lock:
                return False
            if not w.released:
                self._release_locked(w)
            return True

    def finish_wait(self, w: Waiter) -> None:
        """Called by a woken thread: forget the waiter (it was marked busy by whoever woke it)."""
        with self._mu:
            self._forget_locked(w)

    def loop_woken(self, w: Waiter) -> bool:
        """An event loop's selector returned (I/O or wake-up): may the loop run now?

        True: the gate is open, the loop is marked busy. False: outside phase 0; the loop must hold
        its events and call :meth:`wait_gate` (it stays counted idle until the next phase 0).
        """
        with self._mu:
            if w.released:
                self._forget_locked(w)
                return True
            w.released = True
            self._forget_locked(w)
            return self._gate_open

    def wait_gate(self) -> None:
        """Block the calling thread (counted idle) until the next phase 0 opens the gate.

        Counted idle and queued on the gate in one step: a thread counted idle but not yet queued let the
        phase that was just opening end without it (the script's main thread then started a phase late, its
        MAVSDK threads made at t=0.02 s instead of 0, in about 1 run of 30 under load)."""
        lock = _thread.allocate_lock()
        lock.acquire()
        w = Waiter(_thread.get_ident(), lock, None, None)
        self._reads.pop(w.ident, None)
        with self._mu:
            if self.closed or self._gate_open:
                return  # the run is over, or phase 0 is on: run now
            self._idle[w.ident] = w
            self._by_lock[id(lock)] = w
            self._gate_waiters.append(w)
            if self._started:
                self._want_phase_locked()
        self._poke()
        w.lock.acquire()
        self.finish_wait(w)

    def wait_first_phase(self) -> None:
        """The main thread, before running the script: wait for the first phase 0."""
        self.wait_gate()

    def thread_done(self, ident: int | None = None) -> None:
        """A script thread has finished (or the main script returned): never wait for it again."""
        with self._mu:
            self._done_threads.add(ident if ident is not None else _thread.get_ident())
        self._poke()

    def thread_resumed(self, ident: int | None = None) -> None:
        with self._mu:
            self._done_threads.discard(ident if ident is not None else _thread.get_ident())

    def take_delivery(self, port: int | None = None, timeout_s: float | None = None) -> Delivery | None:
        """The oldest delivered packet (for ``port``, or any), waiting up to ``timeout_s`` of sim time for one
        (None: until one comes); None on timeout or when the run is over. Script threads only."""
        deadline = None if timeout_s is None else self._now_ns + round(timeout_s * NS_PER_S)
        while True:
            # deliveries only arrive between phases, never while this runs
            if port is None:
                if self.inbox:
                    return self.inbox.popleft()
            else:
                found = self.pop_delivery(port)
                if found is not None:
                    return found
            if self.closed or (deadline is not None and self._now_ns >= deadline):
                return None
            w = self.new_waiter(deadline_ns=deadline, inbox=True)
            w.lock.acquire()
            self.finish_wait(w)

    def pop_delivery(self, port: int) -> Delivery | None:
        """The oldest delivered packet for ``port``, or None at once (script threads, in phase 0)."""
        inbox = self.inbox
        for i, d in enumerate(inbox):
            if d.port == port:
                del inbox[i]
                return d
        return None

    def has_delivery(self, port: int) -> bool:
        return any(d.port == port for d in self.inbox)

    def queue_packet(self, dst: int, port: int, payload: bytes) -> None:
        """ENQUEUE a packet for the network; sent before this phase's END-TICK-0."""
        with self._mu:
            self.stats.outbox.append(_Outgoing(dst, port, bytes(payload)))

    # -- internals -----------------------------------------------------------------------------

    def _tracked(self) -> bool:
        """Whether the calling thread's waits are sim-time waits: a script thread's. Not the harness's own, and not
        a thread a C library made that runs a Python callback (MAVSDK's, ``threading._DummyThread``): the shim
        counts it busy until the callback returns, so a sim-time wait there would wait for a phase that cannot
        come (a callback that read the clock ``ZENO_READS`` times stalled a run)."""
        if not self._started:
            return False
        t = threading.current_thread()
        return not t.name.startswith(INFRA_THREAD_PREFIX) and not isinstance(t, threading._DummyThread)

    def _poke(self) -> None:
        if self.native is not None:
            self.native.poke()
        if self._signal.locked():
            try:
                self._signal.release()
            except RuntimeError:
                pass

    def _release_locked(self, w: Waiter, wake: bool = True) -> None:
        """Mark ``w``'s thread busy and let it run. Only while the gate is open (or at close)."""
        if w.released:
            return
        if not self._gate_open:
            if w not in self._gate_waiters:
                self._gate_waiters.append(w)
                if wake:  # between phases: ask for one (within a phase it runs when the gate opens again)
                    self._want_phase_locked()
            return
        w.released = True
        self._idle.pop(w.ident, None)
        if w.wake is not None:
            w.wake()
        else:
            self._unlock(w)

    def want_phase(self) -> None:
        """Ask the channel for a phase 0 (WAKE), once between two phases."""
        with self._mu:
            self._want_phase_locked()

    def _want_phase_locked(self) -> None:
        if self._in_phase:
            return  # the gate opens again within this phase (after the library's turn, or a settle)
        if not self._wake_requested and self.request_phase is not None:
            self._wake_requested = True
            self.request_phase()

    @staticmethod
    def _unlock(w: Waiter) -> None:
        try:
            w.lock.release()
        except RuntimeError:
            pass

    def _forget_locked(self, w: Waiter) -> None:
        if self._idle.get(w.ident) is w:
            del self._idle[w.ident]
        self._by_lock.pop(id(w.lock), None)
        if w in self._timed:
            self._timed.remove(w)
        if w in self._inbox_waiters:
            self._inbox_waiters.remove(w)

    def _is_script_thread(self, t: threading.Thread) -> bool:
        """Whether ``t`` runs the script's work (and so must be idle for phase 0 to end).

        The main thread, threads whose target is the script's own code, and thread-pool workers (they run
        the script's functions) do. Service threads of installed libraries (gRPC's poller, mavsdk-grpc's
        server-output reader…) do not: they sit outside the simulation like the autopilot, and what they
        produce reaches the script only through its event loop, which is gated.
        """
        ident = t.ident
        assert ident is not None
        known = self._script_threads.get(ident)
        if known is None:
            known = t is threading.main_thread() or _thread_code_is_script(t)
            self._script_threads[ident] = known
        return known

    def _all_idle_locked(self) -> bool:
        """The one idle predicate: no thread of MAVSDK's core is busy, and every script thread waits."""
        if self.native is not None and self.native.busy():
            return False
        return not self._busy_locked(first_only=True)

    def _busy_locked(self, first_only: bool = False) -> list[tuple[threading.Thread, str]]:
        busy: list[tuple[threading.Thread, str]] = []
        frames: dict[int, FrameType] | None = None
        threads = threading.enumerate()
        for t in threads:
            ident = t.ident
            if t.name.startswith(INFRA_THREAD_PREFIX) or isinstance(t, threading._DummyThread):
                continue
            if ident is None:  # being started (Thread.start waits for it): it runs in this phase, so wait for it
                busy.append((t, "starting"))
                if first_only:
                    break
                continue
            if ident in self._done_threads or ident in self._idle:
                continue
            if self.native is not None and self.native.thread_waiting(ident):
                continue  # waits inside the library on the sim clock (a blocking MAVSDK call in an executor)
            if not self._is_script_thread(t):
                continue
            if frames is None:
                frames = sys._current_frames()
            frame = frames.get(ident)
            if frame is None:
                continue  # the thread has ended
            code = frame.f_code
            where = (code.co_filename.rsplit("/", 1)[-1], code.co_name)
            if where in _IDLE_FRAMES and not (where == _JOIN_FRAME and _joins_ended(frame, threads)):
                continue
            busy.append((t, f"{code.co_filename}:{frame.f_lineno} in {code.co_name}"))
            if first_only:
                break
        return busy


def _in_kernel(t: threading.Thread) -> str:
    """The system call a busy thread is in (a C call outside every patched one), for the watchdog's message."""
    try:
        with open(f"/proc/self/task/{t.native_id}/syscall") as f:
            first = f.read().split(" ", 1)[0]
    except OSError:
        return ""
    if first == "running" or not first.isdigit():
        return ""
    name = _SYSCALLS.get(int(first), f"system call {first}")
    return f" (blocked in {name}: a C call the sim clock does not know)"


_SYSCALLS = {
    0: "read",
    7: "poll",
    23: "select",
    202: "futex (a lock or condition variable)",
    35: "nanosleep",
    230: "clock_nanosleep",
    61: "wait4",
    45: "recvfrom",
    47: "recvmsg",
    43: "accept",
    232: "epoll_wait",
    281: "epoll_pwait",
    34: "pause",
    130: "sigsuspend",
}
"""x86-64 system call numbers of the usual blocking calls."""


def _joins_ended(frame: FrameType, threads: list[threading.Thread]) -> bool:
    """Whether the ``Thread.join`` in ``frame`` waits for a thread whose Python part is over (see ``_JOIN_FRAME``)."""
    joined = frame.f_locals.get("self")
    return isinstance(joined, threading.Thread) and all(t is not joined for t in threads)


_LIBRARY_ROOTS = tuple(
    {
        sys.prefix,
        sys.base_prefix,
        sys.exec_prefix,
        os.path.dirname(os.__file__),
        os.path.dirname(os.path.dirname(__file__)),
    }
)
_WORKER_CODE = {("thread.py", "_worker")}
_SERVICE_MODULES = frozenset({"grpc", "mavsdk_grpc", "mavsdk"})
"""Libraries whose own threads sit outside the simulation (see ``_is_script_thread``)."""


def _thread_code_is_script(t: threading.Thread) -> bool:
    target = getattr(t, "_target", None)
    func = target if target is not None else getattr(type(t), "run", None)
    code = getattr(func, "__code__", None)
    if code is not None and (code.co_filename.rsplit("/", 1)[-1], code.co_name) in _WORKER_CODE:
        return True
    module_name = getattr(func, "__module__", None) or ""
    if module_name == "__main__":
        return True
    module = sys.modules.get(module_name)
    filename = getattr(module, "__file__", None) or (code.co_filename if code is not None else "")
    if not filename or not os.path.isabs(filename):
        return True  # unknown origin: be safe, wait for it
    if not filename.startswith(_LIBRARY_ROOTS):
        return True
    # A library's thread works for the script (DroneKit's reader and writer, pymavlink's, a timer): it must be
    # idle for phase 0 to end, from its first moment on — else what it does at start-up lands in whichever
    # phase the machine's pace gives it. Only service threads of libraries that block in C for the whole run
    # and reach the script through its gated event loop stay outside (gRPC's poller, mavsdk-grpc's readers).
    return module_name.split(".", 1)[0] not in _SERVICE_MODULES
