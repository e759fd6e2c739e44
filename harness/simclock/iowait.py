"""Waits for I/O on the sim clock: ``select``, ``poll``, ``epoll``, ``selectors`` and blocking sockets.

A thread of a mission that waits for a file descriptor (pymavlink's ``select(..., 0.05)`` loop, DroneKit's
reader thread, a blocking ``recvfrom`` with ``settimeout(5)``) is *idle* for the sim clock: phase 0 may end
while it waits, its timeout is sim time, and when data arrives between two phases the thread runs only in
the next phase 0 (the runtime sends WAKE so that a channel using lookahead includes the mission again).
The mechanism is the one of the asyncio loop's ``SimSelector``: the thread registers as a waiter whose
release writes to a per-thread pipe, then blocks in a real ``select`` on its descriptors plus that pipe.

Threads the harness owns (and waits with a zero timeout) keep the original behaviour.
"""

from __future__ import annotations

import contextlib
import os
import select
import selectors
import threading
from collections.abc import Callable, Iterable
from typing import Any

from harness.core.clock import NS_PER_S
from harness.simclock.runtime import SimRuntime
from harness.simclock.threads import Kind

real_select = select.select
real_poll = select.poll
real_epoll = getattr(select, "epoll", None)

_tls = threading.local()


def _wake_pipe() -> tuple[int, int]:
    pipe: tuple[int, int] | None = getattr(_tls, "pipe", None)
    if pipe is None:
        r, w = os.pipe()
        os.set_blocking(r, False)
        os.set_blocking(w, False)
        pipe = _tls.pipe = (r, w)
    return pipe


def _drain(fd: int) -> None:
    with contextlib.suppress(BlockingIOError, InterruptedError):
        while os.read(fd, 512):
            pass


def deadline_of(rt: SimRuntime, timeout_s: float | None) -> int | None:
    return None if timeout_s is None else rt.now_ns() + max(1, round(timeout_s * NS_PER_S))


def wait(
    rt: SimRuntime,
    rfds: Iterable[int],
    wfds: Iterable[int] = (),
    deadline_ns: int | None = None,
    inbox: bool = False,
) -> None:
    """Block the calling script thread, counted idle, until a descriptor is ready, a packet is delivered
    (``inbox``), the sim deadline passes or the run ends. Returns in phase 0; the caller re-polls."""
    r, w = _wake_pipe()

    def wake() -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(w, b"\0")

    rl, wl = list(rfds), list(wfds)
    vehicle = [fd for fd in rl if fd in rt.mavlink_fds]
    waiter = rt.new_waiter(
        Kind.IO,
        deadline_ns=deadline_ns,
        wake=wake,
        inbox=inbox,
        rfds=tuple(rl),
        wfds=tuple(wl),
        every_phase=bool(vehicle),
    )
    # Not the vehicle's sockets: the runtime lets their data in itself, at a round of the phase (its start, after a
    # settle, once the script is idle), never at the wall-clock moment it arrives while other script threads run.
    # The vehicle answers a command at once, in the middle of the phase: a reader woken by that answer ran beside
    # the thread that sent the command, and which of the two got further first was the machine's pace (DroneKit's
    # reader took the vehicle's hello heartbeat before or after the main thread had added its capabilities
    # listener: one ping-pong chain in some runs, two in others). Between phases nothing is lost: a thread waiting
    # for its vehicle takes part in every phase (``every_phase``), whose start looks into its sockets.
    rl = [fd for fd in rl if fd not in vehicle]
    rl.append(r)
    while True:
        try:
            real_select(rl, wl, [], None)
            break
        except InterruptedError:
            continue
        except (OSError, ValueError):
            break  # a descriptor was closed under us: let the caller find out
    _drain(r)
    if not rt.loop_woken(waiter):
        rt.wait_gate()  # I/O arrived outside phase 0: hold it until the gate opens


def _fd(obj: Any) -> int:
    return obj if isinstance(obj, int) else int(obj.fileno())


def _held(obj: Any) -> bool:
    """Whether the runtime holds data for ``obj`` (a radio socket's delivered packets)."""
    ready = getattr(obj, "_sim_ready", None)
    return ready is not None and bool(ready())


def _on_inbox(obj: Any) -> bool:
    waits = getattr(obj, "_waits_on_inbox", None)
    return waits is not None and bool(waits())


def make_select(rt: SimRuntime) -> Callable[..., tuple[list[Any], list[Any], list[Any]]]:
    def sim_select(
        rlist: Iterable[Any], wlist: Iterable[Any], xlist: Iterable[Any], timeout: float | None = None
    ) -> tuple[list[Any], list[Any], list[Any]]:
        rl, wl, xl = list(rlist), list(wlist), list(xlist)
        if not rt.on_sim_time():
            return real_select(rl, wl, xl, timeout)
        if timeout is not None and timeout < 0:
            raise ValueError("timeout must be non-negative")
        deadline = deadline_of(rt, timeout)
        while True:
            virtual = [o for o in rl if _held(o)]
            ready = real_select(rl, wl, xl, 0)
            if virtual:
                ready = ([*ready[0], *(o for o in virtual if o not in ready[0])], ready[1], ready[2])
            if any(ready) or timeout == 0 or rt.closed:
                return ready
            if deadline is not None and rt.now_ns() >= deadline:
                return [], [], []
            inbox = any(_on_inbox(o) for o in rl)
            wait(rt, [_fd(o) for o in (*rl, *xl)], [_fd(o) for o in wl], deadline, inbox)

    return sim_select


_READ = select.POLLIN | select.POLLPRI
_WRITE = select.POLLOUT


class _PollBase:
    """What ``select.poll`` and ``select.epoll`` objects share here: the registered interest, for waits."""

    _inner: Any
    _rt: SimRuntime

    def __init__(self) -> None:
        self._interest: dict[int, int] = {}

    def register(self, fd: Any, eventmask: int = _READ | _WRITE) -> None:
        self._inner.register(fd, eventmask)
        self._interest[_fd(fd)] = eventmask

    def modify(self, fd: Any, eventmask: int) -> None:
        self._inner.modify(fd, eventmask)
        self._interest[_fd(fd)] = eventmask

    def unregister(self, fd: Any) -> None:
        self._inner.unregister(fd)
        self._interest.pop(_fd(fd), None)

    def _wait_until(self, poll_now: Callable[[], list[Any]], timeout_s: float | None) -> list[Any]:
        rt = self._rt
        deadline = deadline_of(rt, timeout_s)
        while True:
            events = poll_now()
            if events or timeout_s == 0 or rt.closed:
                return events
            if deadline is not None and rt.now_ns() >= deadline:
                return []
            rfds = [fd for fd, m in self._interest.items() if m & _READ]
            wfds = [fd for fd, m in self._interest.items() if m & _WRITE]
            wait(rt, rfds, wfds, deadline)


def make_poll_class(rt: SimRuntime) -> type:
    class SimPoll(_PollBase):
        """``select.poll()`` whose blocking waits are sim-time waits."""

        def __init__(self) -> None:
            super().__init__()
            self._rt = rt
            self._inner = real_poll()

        def poll(self, timeout: float | None = None) -> list[tuple[int, int]]:
            if not rt.on_sim_time():
                return list(self._inner.poll(timeout))
            t = None if timeout is None or timeout < 0 else timeout / 1000.0
            return self._wait_until(lambda: list(self._inner.poll(0)), t)

    return SimPoll


def make_epoll_class(rt: SimRuntime) -> type:
    assert real_epoll is not None

    class SimEpoll(_PollBase):
        """``select.epoll()`` whose blocking waits are sim-time waits."""

        def __init__(self, sizehint: int = -1, flags: int = 0) -> None:
            super().__init__()
            self._rt = rt
            assert real_epoll is not None
            self._inner = real_epoll(sizehint, flags)

        def register(self, fd: Any, eventmask: int = select.EPOLLIN | select.EPOLLOUT | select.EPOLLPRI) -> None:
            super().register(fd, eventmask)

        def poll(self, timeout: float | None = None, maxevents: int = -1) -> list[tuple[int, int]]:
            if not rt.on_sim_time():
                return list(self._inner.poll(timeout, maxevents))
            t = None if timeout is None or timeout < 0 else timeout
            return self._wait_until(lambda: list(self._inner.poll(0, maxevents)), t)

        def fileno(self) -> int:
            return int(self._inner.fileno())

        def close(self) -> None:
            self._inner.close()

        @property
        def closed(self) -> bool:
            return bool(self._inner.closed)

        def __enter__(self) -> Any:
            return self

        def __exit__(self, *_exc: object) -> None:
            self.close()

    return SimEpoll


class RawEpollSelector(selectors.EpollSelector):
    """The real epoll selector, for the asyncio loop's own ``SimSelector`` (which waits on the sim clock
    itself) once ``selectors`` is patched."""

    _selector_cls = real_epoll


def patches(rt: SimRuntime) -> dict[tuple[object, str], object]:
    """Everything this module replaces: ``(owner, name) → replacement``."""
    sim_select = make_select(rt)
    out: dict[tuple[object, str], object] = {
        (select, "select"): sim_select,
        (select, "poll"): make_poll_class(rt),
        (selectors.PollSelector, "_selector_cls"): make_poll_class(rt),
        (selectors.SelectSelector, "_select"): staticmethod(sim_select),
    }
    if real_epoll is not None:
        epoll_cls = make_epoll_class(rt)
        out[(select, "epoll")] = epoll_cls
        out[(selectors.EpollSelector, "_selector_cls")] = epoll_cls
    return out
