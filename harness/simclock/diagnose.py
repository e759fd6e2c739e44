"""What the watchdog and the trace say about a thread that keeps phase 0 open: where it is and which call.

Stack frames are read here only to explain, never to decide: the idle decision is the registry's
(``threads.Registry.first_busy``).
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Container

from harness.simclock.threads import Registry, Role

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


def in_kernel(t: threading.Thread) -> str:
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


def where(t: threading.Thread) -> str:
    """``file:line in function`` of a thread's innermost Python frame, or why there is none."""
    if t.ident is None:
        return "starting"
    frame = sys._current_frames().get(t.ident)
    if frame is None:
        return "ended"
    code = frame.f_code
    return f"{code.co_filename}:{frame.f_lineno} in {code.co_name}"


def busy_line(t: threading.Thread) -> str:
    return f"{t.name} at {where(t)}{in_kernel(t) if t.ident is not None else ''}"


def why_idle(registry: Registry, waiting: Container[int]) -> str:
    """Each thread of the registry and why it counts idle (its blocker's kind, ``in C``), ``busy`` or ``outside``."""
    why = []
    for ident, entry in registry.threads.items():
        if entry.role is Role.SCRIPT:
            why.append(f"{entry.thread.name}={registry.waits(ident, waiting) or 'busy'}")
        elif entry.role is Role.SERVICE:
            why.append(f"{entry.thread.name}=outside")
    return " ".join(why)
