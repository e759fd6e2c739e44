"""A C library's threads on the sim clock: ``simtime.c`` (and its parts), built once per machine, GOT-patched into the
library.

MAVSDK's native core (``mavsdk/lib/libcmavsdk.so``, which both MAVSDK APIs run on in a mission) is linked
dynamically against libc, with libstdc++ inside it: every clock read, sleep, condition variable, futex, poll,
receive and thread it makes goes through its own GOT. :func:`attach` rewrites those GOT entries to
``simtime.c``, so that the library's timers, timeouts and waits follow sim time and its threads take part in
the phase-0 idle decision of :class:`~harness.simclock.runtime.SimRuntime` (see ``docs/simclock.md``).

The shared object is compiled when the package is built (``setup.py``: it ships in the wheel beside its sources,
named by their hash, ``simtime-<hash>.so``). Where a build has none (no C compiler when it was built, or a source
edited since), it is compiled with the machine's C compiler the first time it is
needed (about 0.3 s) into the user's cache directory, keyed the same way; a launcher builds it before it starts
missions, so a run of a hundred missions compiles once. Without either the library keeps the wall clock: one
warning says so, and everything else works as before.

Finding and compiling the shared object: :mod:`harness.simclock.shim`.
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from harness.simclock.shim import CHILD, build

log = logging.getLogger(__name__)

NO_DEADLINE = (1 << 63) - 1


class _State(ctypes.Structure):
    """``hs_state`` (simtime.h)."""

    _fields_ = (
        ("generation", ctypes.c_uint64),
        ("busy", ctypes.c_int64),
        ("sent", ctypes.c_uint64),
        ("next_deadline", ctypes.c_int64),
        ("waits_for_io", ctypes.c_int64),
        ("nwaiting", ctypes.c_int64),
    )


@dataclass(frozen=True)
class NativeState:
    """The shim's state in one look (``hs_snapshot``, under its lock): what :meth:`NativeClock.generation`,
    :c:func:`hs_busy`, :meth:`~NativeClock.sent`, ``hs_next_deadline`` and ``hs_waits_for_io``
    answer, and the threads ``hs_thread_waiting`` answers 1 for."""

    generation: int
    busy: int
    """Threads the shim tracks (the library's, C extensions', child processes) that are not waiting."""
    sent: int
    next_deadline_ns: int
    """The earliest sim deadline of a wait or an armed timer (``NO_DEADLINE``: none)."""
    waits_for_io: bool
    waiting: frozenset[int]
    """The threads (``threading`` idents, pthread_t) inside a wait of the shim that has not ended."""


def build_all() -> None:
    """Build the mission's side and the child processes' side (once per machine; no-op when cached)."""
    if sys.platform.startswith("linux") and build() is not None:
        build(CHILD)


@dataclass(eq=False)
class NativeClock:
    """The shim in this process: the clock thread's handle on the C threads of the patched library."""

    lib: ctypes.CDLL
    patched: int
    """GOT entries rewritten."""

    def begin(self, t_ns: int) -> None:
        self.lib.hs_begin(t_ns)

    def try_close(self, generation: int | None = None) -> bool:
        """End phase 0 if every library thread is idle and nothing changed since ``generation`` (read before the
        caller found the script's threads idle; None: now)."""
        return bool(self.lib.hs_try_close(self.generation() if generation is None else generation))

    def reopen(self) -> None:
        self.lib.hs_reopen()

    def pause(self) -> None:
        """Shut the gate without ending the phase (a settle is in flight); :meth:`reopen` opens it again."""
        self.lib.hs_pause()

    def release_ready(self) -> int:
        """Let every library thread whose descriptors are ready run; how many."""
        return int(self.lib.hs_release_ready())

    def wait_idle(self, timeout_ns: int) -> bool:
        """Wait (wall clock, at most ``timeout_ns``) until every library thread waits with nothing ready."""
        return bool(self.lib.hs_wait_library_idle(timeout_ns))

    def sent(self) -> int:
        return int(self.lib.hs_sent())

    def generation(self) -> int:
        return int(self.lib.hs_generation())

    def snapshot(self) -> NativeState:
        """The shim's state in one look, taken under its lock (five calls could each see another)."""
        state = _State()
        room = 64
        while True:
            idents = (ctypes.c_uint64 * room)()
            n = int(self.lib.hs_snapshot(ctypes.byref(state), idents, room))
            if n <= room:
                break
            room = 2 * n  # more threads wait than there was room for: look again
        return NativeState(
            generation=state.generation,
            busy=state.busy,
            sent=state.sent,
            next_deadline_ns=state.next_deadline,
            waits_for_io=bool(state.waits_for_io),
            waiting=frozenset(idents[:n]),
        )

    def wait_change(self, generation: int, timeout_ns: int) -> None:
        self.lib.hs_wait_change(generation, timeout_ns)

    def poke(self) -> None:
        self.lib.hs_poke()

    def close(self) -> None:
        self.lib.hs_close()

    def set_wall(self, wall: bool = True) -> None:
        """The calling thread is the harness's own (the clock thread; the main thread once the script has ended):
        its clock and waits stay real in every library the shim patched."""
        self.lib.hs_set_wall(int(wall))

    def interrupt(self, ident: int) -> bool:
        """End the wait of thread ``ident`` inside the shim for a signal (its call returns EINTR)."""
        return bool(self.lib.hs_interrupt(ident))

    def want_fd(self) -> int:
        """An eventfd, readable when a wait outside MAVSDK's core became ready between phases: the mission must ask
        the channel for a phase (WAKE), as for a Python thread's wait (``SimRuntime.want_phase``)."""
        return int(self.lib.hs_want_fd())

    def describe(self) -> str:
        buf = ctypes.create_string_buffer(8192)
        self.lib.hs_describe(buf, len(buf))
        return buf.value.decode(errors="replace")


def _load(path: Path) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    i64, u64 = ctypes.c_int64, ctypes.c_uint64
    lib.hs_configure.argtypes = [i64, i64]
    lib.hs_begin.argtypes = [i64]
    lib.hs_next_deadline.restype = i64
    lib.hs_thread_waiting.argtypes = [u64]
    lib.hs_sent.restype = u64
    lib.hs_generation.restype = u64
    lib.hs_snapshot.argtypes = [ctypes.POINTER(_State), ctypes.POINTER(u64), ctypes.c_int]
    lib.hs_try_close.argtypes = [u64]
    lib.hs_wait_change.argtypes = [u64, i64]
    lib.hs_wait_library_idle.argtypes = [i64]
    lib.hs_patch.argtypes = [ctypes.c_char_p]
    lib.hs_describe.argtypes = [ctypes.c_char_p, ctypes.c_int]
    lib.hs_set_wall.argtypes = [ctypes.c_int]
    lib.hs_interrupt.argtypes = [u64]
    lib.hs_children.argtypes = [ctypes.c_char_p]
    lib.hs_become_child.argtypes = [ctypes.c_char_p]
    return lib


_ATTACHED: NativeClock | None = None
_LIBRARIES: set[str] = set()


def _shim(epoch_ns: int, now_ns: int) -> NativeClock | None:
    """The shim loaded and configured in this process (once); None where it cannot be built."""
    global _ATTACHED
    if _ATTACHED is None:
        if not sys.platform.startswith("linux"):
            return None
        path = build()
        if path is None:
            return None
        _ATTACHED = NativeClock(_load(path), 0)
    _ATTACHED.lib.hs_configure(epoch_ns, now_ns)
    return _ATTACHED


def attach_process(epoch_ns: int, now_ns: int, forget_python: Callable[[], None]) -> NativeClock | None:
    """Put the C-level waits of the whole process on the sim clock (``hs_patch_process``): the interpreter's timed
    lock waits (``Lock.acquire(timeout=…)``, ``SimpleQueue.get(timeout=…)``), and the clock reads, sleeps and timed
    waits of every C extension and library it loads, now or later (libzmq's poll, a C function called through
    ctypes). Idempotent; None where the shim cannot be built.

    ``forget_python`` runs first thing in a process forked without exec (multiprocessing's fork): it takes the
    Python-level patches out, so that the child's time and waits are all C calls, which ``simchild.c`` has."""
    clock = _shim(epoch_ns, now_ns)
    if clock is None:
        return None
    child_lib = build(CHILD)  # before the process's own waits for a child (the compiler) are sim-time waits
    clock.patched += int(clock.lib.hs_patch_process())
    log.debug("the process: %d calls on the sim clock", clock.patched)
    if child_lib is not None:
        _children(clock, epoch_ns, child_lib, forget_python)
    return clock


_CHILD_ENV = ("HARNESS_SIMTIME_PRELOADED", "HARNESS_SIMTIME_PARENT", "HARNESS_SIMTIME_EPOCH")


def _children(clock: NativeClock, epoch_ns: int, child_lib: Path, forget_python: Callable[[], None]) -> None:
    """Child processes join this process's lockstep (``simchild.c``): programs it starts get the child side in
    ``LD_PRELOAD`` and the address of the children's server (``hs_children``) in their environment; a process it
    forks without exec switches to the child side in its first moment (``hs_become_child``)."""
    name = f"harness-simtime-{os.getpid()}-{os.urandom(4).hex()}"
    if not clock.lib.hs_children(name.encode()):
        log.warning("cannot listen for child processes (%s): they stay on the wall clock", name)
        return
    preload = os.environ.get("LD_PRELOAD", "")
    os.environ["LD_PRELOAD"] = f"{child_lib} {preload}".strip()
    os.environ.update(zip(_CHILD_ENV, ("1", name, str(epoch_ns)), strict=True))

    def become_child() -> None:
        forget_python()
        if not clock.lib.hs_become_child(str(child_lib).encode()):
            log.warning("a forked process could not join the mission's lockstep: it runs on the wall clock")

    os.register_at_fork(after_in_child=become_child)


def attached(library: str) -> bool:
    """Whether :func:`attach` has put ``library`` on the sim clock in this process."""
    return library in _LIBRARIES


def attach(library: str, epoch_ns: int, now_ns: int) -> NativeClock | None:
    """Put the threads of the loaded library whose path contains ``library`` on the sim clock: its clock, waits,
    I/O and threads (MAVSDK's core, whose threads take part in the idle decision).

    Idempotent; None when the shim cannot be built (no compiler) or the library has nothing to patch."""
    clock = _shim(epoch_ns, now_ns)
    if clock is None:
        return None
    if library in _LIBRARIES:
        return clock
    patched = int(clock.lib.hs_patch(library.encode()))
    if patched == 0:
        log.warning("%s is not loaded or imports nothing to patch: its threads stay on the wall clock", library)
        return None
    log.debug("%s: %d calls on the sim clock", library, patched)
    _LIBRARIES.add(library)
    clock.patched += patched
    return clock
