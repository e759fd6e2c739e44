"""A child process dies with the process that started it, even when that one is killed with ``kill -9``.

Linux's ``PR_SET_PDEATHSIG`` has the kernel send the child SIGKILL when its parent dies. Setting it
between fork and exec (``preexec_fn``) forces ``subprocess`` into a full ``fork()`` of the parent — tens
of milliseconds per child for a process the size of ``harness run``, once per mission — so the harness's
own children set it on themselves instead, first thing (:func:`hold_on`), and the parent spawns them with
``vfork`` (no ``preexec_fn``; ``process_group=0`` gives each its own group). The window before the child
has set it is closed by a check: the parent's pid travels in :data:`PARENT_ENV`, and a child whose parent
is no longer that pid (it died in between: the child was re-parented) exits at once.

Programs that are not the harness's own (the Rerun viewer) cannot do this: :func:`preexec` is the
``preexec_fn`` for them.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Mapping
from typing import NoReturn

PARENT_ENV = "HARNESS_LIFELINE_PID"
"""The pid of the process whose death must end this one (read and removed by :func:`hold_on`)."""
_PR_SET_PDEATHSIG = 1
ORPHANED_EXIT = 128 + signal.SIGKILL
"""Exit status of a child that found its parent already gone (as if the kernel had SIGKILLed it)."""


def _pdeathsig() -> None:
    try:
        import ctypes  # here: a process that ties nothing need not load it

        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux: the parent's process-group kill on stop() remains
        pass


def preexec() -> None:
    """``preexec_fn`` for a program that is not the harness's own: its own process group, SIGKILL when the
    parent dies. (It costs a full fork of the parent; the harness's own children use :func:`tied_env`.)"""
    os.setpgid(0, 0)
    _pdeathsig()


def tied_env(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` for a harness child that calls :func:`hold_on` first thing: it carries this process's pid."""
    return {**env, PARENT_ENV: str(os.getpid())}


def hold_on() -> None:
    """In a child started with :func:`tied_env`: die (SIGKILL) when the parent dies; exit now if it already
    has. A no-op in a process not started that way. The variable is removed, so that this process's own
    children (a mission script's) are not tied to the wrong parent."""
    parent = os.environ.pop(PARENT_ENV, None)
    if parent is not None and parent.isdigit():
        tie_to(int(parent))


def tie_to(parent: int) -> None:
    """Die (SIGKILL) when the parent process ``parent`` dies; exit now if it already has (a forked child
    ties itself so, :mod:`harness.run.forkserver`)."""
    _pdeathsig()
    if os.getppid() != parent:  # the parent died before the line above: nobody would kill us
        os._exit(ORPHANED_EXIT)


def exit_now(code: int) -> NoReturn:
    """End this process at once with ``code`` (no interpreter teardown: a library may have left a non-daemon
    thread behind), its standard streams flushed first."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    os._exit(code)
