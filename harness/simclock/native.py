"""A C library's threads on the sim clock: ``simtime.c``, built once per machine, GOT-patched into the library.

MAVSDK's native core (``mavsdk/lib/libcmavsdk.so``, which both MAVSDK APIs run on in a mission) is linked
dynamically against libc, with libstdc++ inside it: every clock read, sleep, condition variable, futex, poll,
receive and thread it makes goes through its own GOT. :func:`attach` rewrites those GOT entries to
``simtime.c``, so that the library's timers, timeouts and waits follow sim time and its threads take part in
the phase-0 idle decision of :class:`~harness.simclock.runtime.SimRuntime` (see ``docs/simclock.md``).

The shared object is compiled when the package is built (``setup.py``: it ships in the wheel beside
``simtime.c``, named by the source's hash, ``simtime-<hash>.so``). Where a build has none (no C compiler when it
was built, or ``simtime.c`` edited since), it is compiled with the machine's C compiler the first time it is
needed (about 0.3 s) into the user's cache directory, keyed the same way; a launcher builds it before it starts
missions, so a run of a hundred missions compiles once. Without either the library keeps the wall clock: one
warning says so, and everything else works as before.

Finding and compiling the shared object: :mod:`harness.simclock.shim`.
"""

from __future__ import annotations

import ctypes
import logging
import sys
from dataclasses import dataclass
from pathlib import Path

from harness.simclock.shim import build

log = logging.getLogger(__name__)

NO_DEADLINE = (1 << 63) - 1


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

    def busy(self) -> int:
        return int(self.lib.hs_busy())

    def release_ready(self) -> int:
        """Let every library thread whose descriptors are ready run; how many."""
        return int(self.lib.hs_release_ready())

    def wait_idle(self, timeout_ns: int) -> bool:
        """Wait (wall clock, at most ``timeout_ns``) until every library thread waits with nothing ready."""
        return bool(self.lib.hs_wait_library_idle(timeout_ns))

    def sent(self) -> int:
        return int(self.lib.hs_sent())

    def thread_waiting(self, ident: int) -> bool:
        return bool(self.lib.hs_thread_waiting(ident))

    def next_deadline_ns(self) -> int:
        return int(self.lib.hs_next_deadline())

    def waits_for_io(self) -> bool:
        return bool(self.lib.hs_waits_for_io())

    def generation(self) -> int:
        return int(self.lib.hs_generation())

    def wait_change(self, generation: int, timeout_ns: int) -> None:
        self.lib.hs_wait_change(generation, timeout_ns)

    def poke(self) -> None:
        self.lib.hs_poke()

    def close(self) -> None:
        self.lib.hs_close()

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
    lib.hs_try_close.argtypes = [u64]
    lib.hs_wait_change.argtypes = [u64, i64]
    lib.hs_wait_library_idle.argtypes = [i64]
    lib.hs_patch.argtypes = [ctypes.c_char_p]
    lib.hs_describe.argtypes = [ctypes.c_char_p, ctypes.c_int]
    return lib


_ATTACHED: NativeClock | None = None


def attach(library: str, epoch_ns: int, now_ns: int) -> NativeClock | None:
    """Put the threads of the loaded library whose path contains ``library`` on the sim clock.

    Idempotent; None when the shim cannot be built (no compiler) or the library has nothing to patch."""
    global _ATTACHED
    if _ATTACHED is not None:
        return _ATTACHED
    if not sys.platform.startswith("linux"):
        return None
    path = build()
    if path is None:
        return None
    lib = _load(path)
    lib.hs_configure(epoch_ns, now_ns)
    patched = int(lib.hs_patch(library.encode()))
    if patched == 0:
        log.warning("%s is not loaded or imports nothing to patch: its threads stay on the wall clock", library)
        return None
    log.debug("%s: %d calls on the sim clock", library, patched)
    _ATTACHED = NativeClock(lib, patched)
    return _ATTACHED
