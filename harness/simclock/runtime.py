"""Sim time inside a mission process: the scheduler of phase 0.

A mission process runs only during phase 0 of the ticks. The *clock thread* (see ``mission.py``) calls
:meth:`SimRuntime.run_phase` on every BEGIN-TICK-0: it advances sim time, opens the *gate*, runs the phase's
release rounds (:data:`ROUNDS`) — each until the script is idle again — closes the gate and returns (then
END-TICK-0 goes out). "Idle" is one predicate over one registry (``threads.Registry``): every counted thread of
the script waits, in a blocker it registered (a sim-time sleep, a ``Condition`` wait, an event loop's selector,
an I/O wait, the inbox, the gate, a join) or inside the C shim (``simtime.c``: a MAVSDK call, a C-level wait).

A thread is woken only while the gate is open, and whoever wakes it marks it busy first, under the runtime's
lock: the decision "all idle" and every wake-up are serialised, so no script code ever runs outside phase 0,
whatever arrives on the wall clock (sockets, MAVSDK's C++ threads) in between.

Internal waits here use raw ``_thread`` locks, never ``threading.Condition``, because that is patched.
"""

from __future__ import annotations

import enum
import logging
import select
import signal
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

from harness.core.clock import NS_PER_S, WALL, Clock
from harness.simclock import diagnose
from harness.simclock.gate import Gate
from harness.simclock.mailbox import Delivery, Mailbox, Outgoing
from harness.simclock.native import NO_DEADLINE as NATIVE_NO_DEADLINE
from harness.simclock.native import NativeClock
from harness.simclock.threads import Kind, Waiter
from harness.wire.protocol import EVERY_PHASE, NO_DEADLINE

log = logging.getLogger(__name__)

_real_select = select.select  # captured before ``patch`` makes select.select a sim-time wait
_REPORT_AFTER_NS = 3 * NS_PER_S


class Step(enum.Enum):
    """What a release round did (:data:`ROUNDS`)."""

    NOTHING = "nothing to release: the next round"
    RAN = "released threads: run until idle again"
    SETTLE = "the vehicle must take the script's MAVLink first"
    WAIT = "the library's threads are not done: wait"
    CLOSE = "every round is over: the phase ends"


@dataclass
class PhaseStats:
    phases: int = 0
    last_phase_wall_ns: int = 0
    busy_wall_ns: int = 0


class SimRuntime(Gate):
    """The scheduler of one mission process's phase 0 (the clock thread's side; the threads' side is :class:`Gate`)."""

    def __init__(self, epoch_ns: int, phase_period_ns: int, vehicle: int = -1, wall: Clock = WALL) -> None:
        super().__init__(epoch_ns, wall)
        self.phase_period_ns = phase_period_ns
        self.vehicle = vehicle
        self._timers_open_ns = -1
        self.mail = Mailbox()
        self.stats = PhaseStats()
        self.mavlink_fds: set[int] = set()
        """Descriptors of the script's sockets to its vehicle (``simsocket``)."""
        self.mavlink_sent = 0
        """Datagrams the script sent its vehicle (``simsocket``); phase 0 ends only once they are handled."""
        self._mavlink_synced = 0
        self.settle_mavlink: Callable[[], bool] | None = None
        """Waits (wall clock) until the vehicle has handled everything sent to it; False: it did not answer."""
        self.trace: TextIO | None = None
        """Where every phase 0 that ends is written, with why each thread counted idle (diagnostics)."""
        self.itimer: tuple[int, int] | None = None
        """``signal.setitimer(ITIMER_REAL, …)`` on sim time: (deadline, interval) in ns; SIGALRM at that phase."""

    def timers_held(self) -> bool:
        """Whether event loops' timers that are due now wait: until the phase's due-waits round (:data:`ROUNDS`),
        when the timed waits fall due, as a ``time.sleep`` does.

        A loop woken in the first round (a MAVSDK callback's ``call_soon_threadsafe``) would otherwise run its due
        timers at once, while other threads still deliver this tick's telemetry: a swarm script's 10 Hz control
        task read some vehicles' positions of this tick and some of the last, depending on the machine's pace."""
        return self._started and self._timers_open_ns != self._now_ns

    # -- the clock thread ----------------------------------------------------------------------

    def run_phase(self, t_ns: int, idle_poll_s: float = 0.001) -> tuple[int, bool, bool]:
        """One phase 0 at sim time ``t_ns``: wake what is due, run until idle. Clock thread only.

        First MAVSDK's own threads (``native``) absorb what came in, with every script thread held
        (:meth:`_library_first`); then the gate opens, and the release rounds of :data:`ROUNDS` run in their
        order, each until everything is idle again, so the order in which threads run does not depend on the
        machine's pace.

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
            # machine schedules it late): its wait still counts idle, so look at the sockets themselves.
            self._release_ready_io_locked()
        report_at = start + _REPORT_AFTER_NS
        while True:
            generation = native.generation() if native is not None else 0
            with self._mu:
                step = self._next_round_locked(t_ns, generation) if self._idle_locked() else Step.WAIT
                if step is Step.CLOSE:
                    self._gate_open = False  # the decision "idle" and closing the gate are one step
                    self._in_phase = False
                    self._wake_requested = False
                    lookahead = self._lookahead_locked()
                    if self.trace is not None:
                        self._trace_close_locked(t_ns)
                    break
            if step is Step.SETTLE:
                self._settle()
            elif step is Step.RAN:
                if native is not None:
                    native.reopen()
            elif native is not None:
                native.wait_change(generation, round(idle_poll_s * NS_PER_S))
            else:
                self._signal.acquire(True, idle_poll_s)
            report_at = self._warn_if_slow(start, report_at, "the script")
        self.stats.phases += 1
        self.stats.last_phase_wall_ns = now_wall() - start
        self.stats.busy_wall_ns += self.stats.last_phase_wall_ns
        return lookahead

    def _next_round_locked(self, t_ns: int, generation: int) -> Step:
        """The script is idle: the first round of :data:`ROUNDS` that has something to do, or ``CLOSE``."""
        for _, run in ROUNDS:
            step = run(self, t_ns, generation)
            if step is not Step.NOTHING:
                return step
        return Step.CLOSE

    def _settle_round(self, t_ns: int, generation: int) -> Step:
        """The script sent its vehicle MAVLink in this phase: the vehicle handles it first (:meth:`_settle`)."""
        unsettled = self._sent_locked() != self._mavlink_synced and self.settle_mavlink is not None
        return Step.SETTLE if unsettled else Step.NOTHING

    def _library_round(self, t_ns: int, generation: int) -> Step:
        """The library's threads wait with nothing ready since ``generation``, and their gate shuts: what they handed
        the script before they went idle (a callback's ``call_soon_threadsafe``) is in a socket now."""
        native = self.native
        return Step.NOTHING if native is None or native.try_close(generation) else Step.WAIT

    def _io_round(self, t_ns: int, generation: int) -> Step:
        """Threads whose I/O or notification arrived: a reader thread handles the telemetry of this tick."""
        return Step.RAN if self._release_ready_io_locked() else Step.NOTHING

    def _cut_off_round(self, t_ns: int, generation: int) -> Step:
        """Threads the clock-read limit stopped in the middle of their work (``Kind.CUT_OFF``) go on before the due
        waits: a thread that polls what they compute sees it finished or not at the same point at any pace. Released
        together with the due sleeps, DroneKit's reader (cut off while it took in a 2,767-item parameter list) and
        the main thread (its 0.1 s poll of ``wait_ready``) ran side by side, and the main thread saw the parameters
        complete or not as the machine's pace had it: the script went on 0.1 s earlier in 1 run of 30."""
        return self._time_out_locked(
            [w for w in self.threads.waiting() if w.kind is Kind.CUT_OFF and (w.deadline_ns or 0) <= t_ns]
        )

    def _due_round(self, t_ns: int, generation: int) -> Step:
        """The timed waits that fall due, event loops' timers among them (:meth:`timers_held`), and the signal timer:
        a thread polling with ``time.sleep`` sees what the reader stored."""
        self._timers_open_ns = t_ns
        if self.itimer is not None and self.itimer[0] <= t_ns:
            self._fire_itimer_locked(t_ns)
            return Step.RAN
        return self._time_out_locked(
            [w for w in self.threads.waiting() if w.deadline_ns is not None and w.deadline_ns <= t_ns]
        )

    def _time_out_locked(self, due: list[Waiter]) -> Step:
        """Release waits whose deadline has come (they return ``timed_out``)."""
        for w in due:
            w.timed_out = True
            self._release_locked(w)
        self.waits_released += len(due)
        return Step.RAN if due else Step.NOTHING

    def _idle_locked(self) -> bool:
        """The one idle predicate: no thread of the C shim is busy, and every counted script thread waits."""
        native = self.native
        if native is None:
            return self.threads.first_busy(()) is None
        snap = native.snapshot()
        return not snap.busy and self.threads.first_busy(snap.waiting) is None

    def _sent_locked(self) -> int:
        """MAVLink sent to the vehicle so far: by the script's sockets and by the library on the sim clock."""
        return self.mavlink_sent + (self.native.sent() if self.native is not None else 0)

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
        """The signal timer fell due: SIGALRM goes to the main thread, which runs its handler in this phase: it is
        marked busy first and its wait, Python's or C's, ends (a sleep goes on afterwards)."""
        assert self.itimer is not None
        deadline, interval = self.itimer
        self.itimer = (max(deadline + interval, t_ns + 1), interval) if interval > 0 else None
        main = threading.main_thread().ident
        assert main is not None
        w = self.threads.blocked.get(main)
        if w is not None and (w.released or w.kind is Kind.JOIN):
            w = None  # a join goes on by itself after the handler
        if w is not None:
            w.interrupted = w.released = True  # busy from now on: the handler runs in this phase
            self.threads.unblocked(w)
        signal.pthread_kill(main, signal.SIGALRM)
        if w is not None:
            self._wake(w)
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
                self._release_ready_io_locked()

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
                    if self._idle_locked() and not native.release_ready():
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

    def _release_ready_io_locked(self) -> bool:
        """Let every thread waiting on a descriptor that is ready now run (clock thread, phase 0): whether a thread
        runs in this phase then depends on what is in its sockets, not on when the machine happened to schedule it
        after the data arrived."""
        released = False
        for w in [w for w in self.threads.waiting() if w.rfds or w.wfds]:
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
        snap = self.native.snapshot() if self.native is not None else None
        waiting = list(self.threads.waiting())
        if any(w.gated or w.every_phase for w in waiting):
            return EVERY_PHASE, True, False
        mavlink_wakes = snap is not None and snap.waits_for_io
        if mavlink_wakes and self.vehicle < 0:
            return EVERY_PHASE, True, False
        deadlines = [w.deadline_ns for w in waiting if w.deadline_ns is not None]
        if self.itimer is not None:
            deadlines.append(self.itimer[0])
        if snap is not None and snap.next_deadline_ns != NATIVE_NO_DEADLINE:
            deadlines.append(snap.next_deadline_ns)
        inbox = bool(self.mail.callbacks) or any(w.inbox for w in waiting)
        return min(deadlines, default=NO_DEADLINE), inbox, mavlink_wakes

    def _trace_close_locked(self, t_ns: int) -> None:
        """One line per phase 0 that ended: why each thread counted idle (``HARNESS_SIMTIME_TRACE_DIR``)."""
        assert self.trace is not None
        waiting = self.native.snapshot().waiting if self.native is not None else ()
        self.trace.write(f"{t_ns} close {diagnose.why_idle(self.threads, waiting)}\n")
        self.trace.flush()

    def busy_threads(self) -> list[str]:
        """Where every thread and child process that keeps phase 0 from ending is, and which call it is in
        (diagnostics: the warning before the watchdog drops the mission)."""
        with self._mu:
            snap = self.native.snapshot() if self.native is not None else None
            busy = self.threads.busy(snap.waiting if snap is not None else ())
        described = [self.native.describe()] if self.native is not None and snap is not None and snap.busy else []
        return described + [diagnose.busy_line(e.thread) for e in busy]

    # -- the network (the clock thread between phases; script threads in phase 0) -----------------

    def deliver(self, ds: list[Delivery]) -> None:
        """Packets from the network (clock thread, between phases): wake ``receive`` waiters.

        No WAKE is needed: the channel itself includes a mission that waits on its inbox in the next
        phase 0 when it routes a DELIVER to it (``deliver_wakes`` of END-TICK-0).
        """
        with self._mu:
            self.mail.inbox.extend(ds)
            for w in [w for w in self.threads.waiting() if w.inbox]:
                self._release_locked(w, wake=False)
            callbacks = list(self.mail.callbacks.values())
        for cb in callbacks:
            cb()

    def queue_packet(self, dst: int, port: int, payload: bytes) -> None:
        """ENQUEUE a packet for the network; sent before this phase's END-TICK-0."""
        with self._mu:
            self.mail.outbox.append(Outgoing(dst, port, bytes(payload)))

    def take_outbox(self) -> list[Outgoing]:
        with self._mu:
            return self.mail.take_outbox()

    def add_inbox_callback(self, cb: Callable[[], None]) -> int:
        """Call ``cb`` (on the clock thread) when a packet is delivered; counts as waiting on the inbox.
        Returns a token for :meth:`remove_inbox_callback` (``receive_async`` wakes its event loop this way)."""
        with self._mu:
            return self.mail.add_callback(cb)

    def remove_inbox_callback(self, token: int) -> None:
        with self._mu:
            self.mail.callbacks.pop(token, None)

    def close(self) -> None:
        """The run is over: release every wait so nothing blocks forever."""
        if self.native is not None:
            self.native.close()
        with self._mu:
            self.closed = True
            self._gate_open = True
            for w in list(self.threads.waiting()):
                w.timed_out = True
                self._release_locked(w)


ROUNDS: tuple[tuple[str, Callable[[SimRuntime, int, int], Step]], ...] = (
    ("settle: the vehicle handles the script's MAVLink", SimRuntime._settle_round),
    ("library: MAVSDK's threads idle, their gate shut", SimRuntime._library_round),
    ("ready I/O: readers take in this tick", SimRuntime._io_round),
    ("cut off: threads the clock-read limit stopped go on", SimRuntime._cut_off_round),
    ("due waits: sleeps, timeouts, loop timers, the signal timer", SimRuntime._due_round),
)
"""The release rounds of a phase 0 once the script is idle, in order: the first that has something to do runs, the
script runs until idle again, and the table is walked again from its top; when none has, the phase ends."""
