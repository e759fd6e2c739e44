"""The mission runtime's one registry: every thread of the mission process the scheduler knows, and every blocked one.

Threads are registered when they start (``Thread.start`` and the new thread's first moment, patched by
:func:`patches`), with a :class:`Role` decided once, then:

- ``SCRIPT`` threads (the main thread, the script's own, thread-pool workers, library threads that work for the
  script: DroneKit's reader, a ``threading.Timer``) count in the phase's idle decision and wait on sim time;
- ``SERVICE`` threads of libraries that block in C for the whole run and reach the script only through its gated
  event loop (gRPC's poller, mavsdk-grpc's readers: :data:`SERVICE_MODULES`) wait on sim time but never count;
- ``HARNESS`` threads (:class:`HarnessThread`: the clock thread) wait on the wall clock and never count.

A thread the registry never saw start (one a C library made that calls into Python: MAVSDK's callbacks, seen as
``threading._DummyThread``) neither counts nor waits on sim time: the C shim counts it busy until its callback
returns (``simtime.c``).

Every blocking primitive registers a typed :class:`Waiter` through :meth:`Registry.block` (one per blocked thread)
and the scheduler (``runtime.SimRuntime``) asks one predicate, :meth:`Registry.first_busy`: the phase is idle when
every ``SCRIPT`` thread that has not ended waits — in a registered blocker, or inside the C shim (a MAVSDK call) —
and no thread is starting. All of it is read and written under the runtime's lock.
"""

from __future__ import annotations

import _thread
import enum
import os
import sys
import threading
from collections.abc import Callable, Container, Iterator
from dataclasses import dataclass
from typing import Any, Protocol


class Role(enum.Enum):
    SCRIPT = "script"
    SERVICE = "service"
    HARNESS = "harness"


SIM_ROLES = frozenset({Role.SCRIPT, Role.SERVICE})
"""Roles whose waits are sim-time waits."""


class Kind(enum.Enum):
    """What a blocked thread waits for (the watchdog and the trace say it)."""

    SLEEP = "sleep"
    CUT_OFF = "cut off"
    """Stopped by the clock-read limit (``gate.ZENO_READS``) in the middle of its work: it goes on in the next
    phase in a round of its own, before that phase's due waits (``SimRuntime._cut_off_round``)."""
    CONDITION = "condition"
    """``Condition.wait`` and what is built on it (``Event``, ``Queue``, ``Future.result``…)."""
    LOOP = "event loop"
    """An asyncio loop's selector with nothing ready."""
    IO = "I/O"
    """``select``/``poll``/a socket of the script's (``iowait``)."""
    INBOX = "inbox"
    """A packet from the network simulator (``receive``)."""
    GATE = "gate"
    """The next phase 0."""
    JOIN = "join"
    """``Thread.join`` of a thread that still runs."""


@dataclass(eq=False)
class Waiter:
    """One blocked thread: released by a notify, a due deadline, a delivery or a loop wake-up."""

    ident: int
    lock: _thread.LockType
    kind: Kind = Kind.SLEEP
    deadline_ns: int | None = None
    wake: Callable[[], None] | None = None
    """For event loops and I/O waits: how to wake it (a write to its self-pipe) instead of releasing ``lock``."""
    released: bool = False
    timed_out: bool = False
    interrupted: bool = False
    """Released because a signal timer fired for its thread (``signal.setitimer``): a sleep goes on after the
    handler, as Python's does (PEP 475)."""
    rfds: tuple[int, ...] = ()
    wfds: tuple[int, ...] = ()
    """For I/O waits: the descriptors it waits for, looked at by the phase's ready-I/O round."""
    every_phase: bool = False
    """It waits for its vehicle's MAVLink, which arrives at every phase: no lookahead past this phase."""
    inbox: bool = False
    """A delivered packet releases it."""
    gated: bool = False
    """Released while the gate was shut: it runs when the gate opens (it still counts idle until then)."""
    joins: int | None = None
    """For ``JOIN``: the ident of the joined thread."""


@dataclass(eq=False)
class ThreadEntry:
    thread: threading.Thread
    role: Role
    own: bool
    """Started from the script's own code (the mission waits for these at a normal end, as Python does)."""
    ident: int | None = None
    """None while it is being started (``Thread.start`` waits for it, in this phase): it counts busy."""


class HarnessThread(threading.Thread):
    """A thread of the harness itself in a mission process: wall-clock waits, never part of the idle decision."""


class Registry:
    """Threads by ident and their blockers (see the module's docstring), under the runtime's lock ``mu``: the calls of
    a thread's life (``thread_*``) take it; the others expect it held. ``poke`` tells the scheduler to look again."""

    def __init__(self, mu: _thread.LockType, poke: Callable[[], None]) -> None:
        self._mu = mu
        self._poke = poke
        self.threads: dict[int, ThreadEntry] = {}
        self.starting: dict[int, ThreadEntry] = {}
        """Entries of threads being started, by ``id(thread)``."""
        self.blocked: dict[int, Waiter] = {}
        """The blocker of every blocked thread, by ident (at most one each: a blocked thread makes no other)."""
        self._by_lock: dict[int, Waiter] = {}

    # -- a thread's life, from the patches of ``threading.Thread`` (:func:`patches`) ---------------------

    def adopt_main(self) -> None:
        """The main thread runs the script: it counts (``patch.install``)."""
        main = threading.main_thread()
        assert main.ident is not None
        with self._mu:
            self.threads[main.ident] = ThreadEntry(main, Role.SCRIPT, own=False, ident=main.ident)

    def thread_starting(self, t: threading.Thread) -> None:
        """``Thread.start`` is called (in the starting thread): decide its role; it counts busy until it runs."""
        entry = ThreadEntry(t, *classify(t))
        with self._mu:
            self.starting[id(t)] = entry

    def thread_start_failed(self, t: threading.Thread) -> None:
        with self._mu:
            self.starting.pop(id(t), None)
        self._poke()

    def thread_begins(self, t: threading.Thread, ident: int) -> None:
        """The new thread's first moment (in it)."""
        with self._mu:
            entry = self.starting.pop(id(t), None)
            if entry is None:
                entry = ThreadEntry(t, *classify(t))  # started before the registry patched Thread.start
            entry.ident = ident
            self.threads[ident] = entry

    def thread_done(self, ident: int | None = None) -> None:
        """A thread has finished (or the main script returned): never wait for it again."""
        with self._mu:
            self.end(ident if ident is not None else _thread.get_ident())
        self._poke()

    def end(self, ident: int) -> None:
        """The thread's Python part is over: never wait for it again. A ``Thread.join`` of it counts busy from now
        until it returns. Lock held."""
        self.threads.pop(ident, None)

    def live_own_threads(self) -> list[threading.Thread]:
        """Non-daemon threads the script's own code started that have not ended (the mission waits for them)."""
        with self._mu:
            return [e.thread for e in self.threads.values() if e.own and not e.thread.daemon]

    def role(self, ident: int) -> Role | None:
        entry = self.threads.get(ident)
        return None if entry is None else entry.role

    def alive(self, ident: int | None) -> bool:
        return ident is not None and ident in self.threads

    # -- blockers ------------------------------------------------------------------------------------

    def block(self, w: Waiter) -> None:
        self.blocked[w.ident] = w
        self._by_lock[id(w.lock)] = w

    def forget(self, w: Waiter) -> None:
        if self.blocked.get(w.ident) is w:
            del self.blocked[w.ident]
        if self._by_lock.get(id(w.lock)) is w:
            del self._by_lock[id(w.lock)]

    def unblocked(self, w: Waiter) -> None:
        """``w`` was released: its thread counts busy (it forgets the waiter itself when it runs)."""
        if self.blocked.get(w.ident) is w:
            del self.blocked[w.ident]

    def by_lock(self, lock: _thread.LockType) -> Waiter | None:
        w = self._by_lock.get(id(lock))
        return w if w is not None and w.lock is lock else None

    def waiting(self) -> Iterator[Waiter]:
        """Every blocker not yet released."""
        return (w for w in self.blocked.values() if not w.released)

    # -- the one idle predicate ----------------------------------------------------------------------

    def waits(self, ident: int, elsewhere: Container[int]) -> str | None:
        """Why thread ``ident`` counts idle (its blocker's kind, or ``elsewhere``: it waits inside the C shim), or
        None: it is busy. A join counts idle only while the joined thread still runs Python: once that has ended,
        its OS thread ends on the wall clock and the join returns then — in this phase, not whenever the
        machine's pace gives it."""
        w = self.blocked.get(ident)
        if w is not None and not w.released and (w.kind is not Kind.JOIN or self.alive(w.joins)):
            return w.kind.value
        if ident in elsewhere:
            return "in C"
        return None

    def first_busy(self, elsewhere: Container[int]) -> ThreadEntry | None:
        """The predicate: None when every counted thread waits (``elsewhere``: idents waiting in the C shim)."""
        return next(self._busy(elsewhere), None)

    def busy(self, elsewhere: Container[int]) -> list[ThreadEntry]:
        """Every counted thread that keeps the phase open (diagnostics)."""
        return list(self._busy(elsewhere))

    def _busy(self, elsewhere: Container[int]) -> Iterator[ThreadEntry]:
        """Counted threads being started, then counted threads that do not wait."""
        yield from (e for e in self.starting.values() if e.role is Role.SCRIPT)
        for ident, entry in self.threads.items():
            if entry.role is Role.SCRIPT and self.waits(ident, elsewhere) is None:
                yield entry


# -- roles ---------------------------------------------------------------------------------------------

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
SERVICE_MODULES = frozenset({"grpc", "mavsdk_grpc", "mavsdk"})
"""Libraries whose own threads sit outside the simulation (see :func:`classify`)."""


def classify(t: threading.Thread) -> tuple[Role, bool]:
    """A thread's role and whether the script's own code started it, from what it runs (once, at its start).

    The harness marks its own threads (:class:`HarnessThread`); third-party threads do not register themselves,
    so where their code comes from decides: a library's thread works for the script (DroneKit's reader and
    writer, pymavlink's, a timer, a thread-pool worker) and counts from its first moment — else what it does at
    start-up lands in whichever phase the machine's pace gives it. Only service threads of libraries that block in
    C for the whole run and reach the script through its gated event loop stay outside."""
    if isinstance(t, HarnessThread):
        return Role.HARNESS, False
    target = getattr(t, "_target", None)
    func = target if target is not None else getattr(type(t), "run", None)
    code = getattr(func, "__code__", None)
    if code is not None and (code.co_filename.rsplit("/", 1)[-1], code.co_name) in _WORKER_CODE:
        return Role.SCRIPT, False
    module_name = getattr(func, "__module__", None) or ""
    module = sys.modules.get(module_name)
    filename = getattr(module, "__file__", None) or (code.co_filename if code is not None else "")
    if module_name == "__main__" or not filename or not os.path.isabs(filename):
        return Role.SCRIPT, True  # the script's, or of unknown origin: be safe, wait for it
    if not filename.startswith(_LIBRARY_ROOTS):
        return Role.SCRIPT, True
    if module_name.split(".", 1)[0] in SERVICE_MODULES:
        return Role.SERVICE, False
    return Role.SCRIPT, False


# -- registration: the patches of ``threading.Thread`` ------------------------------------------------


class Scheduler(Protocol):
    """What the patches of ``threading.Thread`` need of the scheduler (``gate.Gate``)."""

    threads: Registry

    def join_waiter(self, joined: threading.Thread) -> Waiter | None: ...

    def finish_wait(self, w: Waiter) -> None: ...


def patches(rt: Scheduler) -> dict[tuple[object, str], Any]:
    """``Thread.start`` registers the thread, its first moment gives it its ident, its end ends it; a counted
    thread's ``Thread.join`` is a ``JOIN`` blocker (``patch.install`` applies these)."""
    cls = threading.Thread
    start, bootstrap_inner, join = cls.start, cls._bootstrap_inner, cls.join  # type: ignore[attr-defined]

    registry = rt.threads

    def sim_start(self: threading.Thread) -> None:
        registry.thread_starting(self)
        try:
            start(self)
        except BaseException:
            registry.thread_start_failed(self)
            raise

    def sim_bootstrap_inner(self: threading.Thread) -> None:
        ident = _thread.get_ident()
        registry.thread_begins(self, ident)
        try:
            bootstrap_inner(self)
        finally:
            registry.thread_done(ident)

    def sim_join(self: threading.Thread, timeout: float | None = None) -> None:
        w = rt.join_waiter(self)
        try:
            join(self, timeout)
        finally:
            if w is not None:
                rt.finish_wait(w)

    return {(cls, "start"): sim_start, (cls, "_bootstrap_inner"): sim_bootstrap_inner, (cls, "join"): sim_join}
