"""The blockers' side of the mission's scheduler: how a script thread waits on sim time, and the gate.

Every blocking primitive of the mission process (a sim-time sleep, ``Condition.wait``, an event loop's selector, an
I/O wait, the radio's inbox, ``Thread.join``) registers a typed blocker in the one registry
(``threads.Registry``) through :meth:`Gate.new_waiter` / :meth:`Gate.join_waiter` and blocks on its lock; the
clock thread's side (``runtime.SimRuntime``, a ``Gate``) releases it. A thread is woken only while the gate is
open (phase 0), and whoever wakes it marks it busy first, under the one lock ``_mu``: the decision "all idle" and
every wake-up are serialised, so no script code ever runs outside phase 0.

Internal waits here use raw ``_thread`` locks, never ``threading.Condition``, because that is patched.
"""

from __future__ import annotations

import _thread
import threading
from collections.abc import Callable

from harness.core.clock import WALL, Clock
from harness.simclock.native import NativeClock
from harness.simclock.threads import SIM_ROLES, Kind, Registry, Role, Waiter

ZENO_READS = 1000
"""A script thread that reads the clock this many times in one phase without waiting waits for the next phase
(``clock_read``): a loop that polls ``time.time()`` without sleeping sees time pass, as on a real vehicle,
instead of stopping the simulation."""


class Gate:
    """Sim time, the gate of phase 0 and the waits of one mission process's threads. All times in nanoseconds."""

    def __init__(self, epoch_ns: int, wall: Clock = WALL) -> None:
        self.wall = wall
        """Real time: phase statistics, and the sleeps of threads that are not the script's."""
        self.epoch_ns = epoch_ns
        self._now_ns = 0
        self._started = False
        self._mu = _thread.allocate_lock()
        self._signal = _thread.allocate_lock()
        self._signal.acquire()
        self._gate_open = False
        self.threads = Registry(self._mu, self._poke)
        """The one registry of the process's threads and their blockers (under ``_mu``)."""
        self.closed = False
        self.request_phase: Callable[[], None] | None = None
        """Called (once between two phases) when script work became ready outside phase 0 on the wall
        clock: the mission runner sends WAKE, so that a channel using lookahead includes it again."""
        self._wake_requested = False
        self._in_phase = False
        """Between the start of a phase 0 and its end: a thread queued on the gate meanwhile runs in it (no WAKE)."""
        self._reads: dict[int, int] = {}
        self.waits_released = 0
        self.native: NativeClock | None = None
        """The C threads of the process on the sim clock (``simtime.c``, ``native.attach``): they take part in the
        idle decision, and what MAVSDK's threads send the vehicle is settled like the script's own MAVLink."""

    # -- reading the clock (any thread) --------------------------------------------------------

    def now_ns(self) -> int:
        return self._now_ns

    def unix_ns(self) -> int:
        return self.epoch_ns + self._now_ns

    def on_sim_time(self) -> bool:
        """Whether the calling thread's waits are sim-time waits: a script thread's or a library service thread's,
        once the first phase has begun. Not the harness's own, and not a thread a C library made that runs a Python
        callback (MAVSDK's): the shim counts it busy until the callback returns, so a sim-time wait there would wait
        for a phase that cannot come."""
        return self._started and self.threads.role(_thread.get_ident()) in SIM_ROLES

    def _open_gate_locked(self) -> None:
        """Script threads may run again: those that were woken while the gate was shut run now."""
        self._gate_open = True
        gated = [w for w in self.threads.waiting() if w.gated]
        for w in gated:
            self._release_locked(w)
        self.waits_released += len(gated)

    # -- the waits of script threads -----------------------------------------------------------

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
        if self.on_sim_time():
            self.sleep_ns(1, Kind.CUT_OFF)

    def sleep_ns(self, ns: int, kind: Kind = Kind.SLEEP) -> None:
        """Block the calling thread for ``ns`` of sim time (at least until a later phase 0)."""
        if not self.on_sim_time():
            self.wall.sleep_ns(ns)
            return
        deadline = self._now_ns + ns
        while self._now_ns < deadline and not self.closed:
            w = self.new_waiter(kind, deadline_ns=deadline)
            try:
                w.lock.acquire()  # a signal handler that raises (a timer's) leaves through here
            finally:
                self.finish_wait(w)
            if not w.interrupted:
                return

    def new_waiter(
        self,
        kind: Kind,
        deadline_ns: int | None = None,
        lock: _thread.LockType | None = None,
        wake: Callable[[], None] | None = None,
        inbox: bool = False,
        rfds: tuple[int, ...] = (),
        wfds: tuple[int, ...] = (),
        every_phase: bool = False,
    ) -> Waiter:
        """Register the calling thread's blocker: idle until released; the caller then blocks on ``lock``.

        With ``wake`` (event loops, I/O waits) the runtime calls ``wake()`` instead of releasing a lock.
        """
        if lock is None:
            lock = _thread.allocate_lock()
            lock.acquire()
        w = Waiter(
            _thread.get_ident(),
            lock,
            kind,
            deadline_ns,
            wake,
            rfds=rfds,
            wfds=wfds,
            every_phase=every_phase,
            inbox=inbox,
        )
        self._reads.pop(w.ident, None)
        with self._mu:
            if self.closed:
                w.released = w.timed_out = True
                self._wake(w)
                return w
            self.threads.block(w)
        self._poke()
        return w

    def join_waiter(self, joined: threading.Thread) -> Waiter | None:
        """A counted thread joins ``joined``: a ``JOIN`` blocker, idle while ``joined`` still runs Python (see
        ``threads.Registry.waits``); None for any other thread (its join is not part of the idle decision)."""
        ident = _thread.get_ident()
        if not self._started or joined.ident == ident:
            return None
        lock = _thread.allocate_lock()
        w = Waiter(ident, lock, Kind.JOIN, joins=joined.ident)
        self._reads.pop(ident, None)
        with self._mu:
            if self.closed or self.threads.role(ident) is not Role.SCRIPT:
                return None
            self.threads.block(w)
        self._poke()
        return w

    def release(self, lock: _thread.LockType) -> bool:
        """Wake the thread blocked on ``lock`` (a Condition's waiter). False if not ours."""
        with self._mu:
            w = self.threads.by_lock(lock)
            if w is None:
                return False
            self._release_locked(w)
            return True

    def finish_wait(self, w: Waiter) -> None:
        """Called by a woken thread: forget the waiter (it was marked busy by whoever woke it)."""
        with self._mu:
            self.threads.forget(w)

    def loop_woken(self, w: Waiter) -> bool:
        """An event loop's selector returned (I/O or wake-up): may the loop run now?

        True: the gate is open, the loop is marked busy. False: outside phase 0; the loop must hold
        its events and call :meth:`wait_gate` (it stays counted idle until the next phase 0).
        """
        with self._mu:
            if w.released:
                self.threads.forget(w)
                return True
            w.released = True
            self.threads.forget(w)
            return self._gate_open

    def wait_gate(self) -> None:
        """Block the calling thread (counted idle) until the next phase 0 opens the gate.

        Counted idle and queued on the gate in one step: a thread counted idle but not yet queued let the
        phase that was just opening end without it (the script's main thread then started a phase late, its
        MAVSDK threads made at t=0.02 s instead of 0, in about 1 run of 30 under load)."""
        lock = _thread.allocate_lock()
        lock.acquire()
        w = Waiter(_thread.get_ident(), lock, Kind.GATE, gated=True)
        self._reads.pop(w.ident, None)
        with self._mu:
            if self.closed or self._gate_open:
                return  # the run is over, or phase 0 is on: run now
            self.threads.block(w)
            if self._started:
                self._want_phase_locked()
        self._poke()
        w.lock.acquire()
        self.finish_wait(w)

    def wait_first_phase(self) -> None:
        """The main thread, before running the script: wait for the first phase 0."""
        self.wait_gate()

    def want_phase(self) -> None:
        """Ask the channel for a phase 0 (WAKE), once between two phases."""
        with self._mu:
            self._want_phase_locked()

    # -- internals -----------------------------------------------------------------------------

    def _poke(self) -> None:
        if self.native is not None:
            self.native.poke()
        if self._signal.locked():
            try:
                self._signal.release()
            except RuntimeError:
                pass

    def _release_locked(self, w: Waiter, wake: bool = True) -> None:
        """Mark ``w``'s thread busy and let it run. Only while the gate is open (or at close): else it is queued on
        the gate (and, between phases, asks for one)."""
        if w.released:
            return
        if not self._gate_open:
            if not w.gated:
                w.gated = True
                if wake:  # between phases: ask for one (within a phase it runs when the gate opens again)
                    self._want_phase_locked()
            return
        w.released = True
        w.gated = False
        self.threads.unblocked(w)
        self._wake(w)

    def _want_phase_locked(self) -> None:
        if self._in_phase:
            return  # the gate opens again within this phase (after the library's turn, or a settle)
        if not self._wake_requested and self.request_phase is not None:
            self._wake_requested = True
            self.request_phase()

    @staticmethod
    def _wake(w: Waiter) -> None:
        if w.wake is not None:
            w.wake()
            return
        try:
            w.lock.release()
        except RuntimeError:
            pass
