"""Reversible patching of time in a mission process: ``time``, ``datetime``, threading waits, asyncio.

:func:`install` replaces, for the whole process, everything in the table of ``docs/simclock.md`` with
versions that read or wait on the :class:`~harness.simclock.runtime.SimRuntime`; :func:`uninstall`
puts every original back. Installing twice is a no-op; so is uninstalling when nothing is installed.
"""

from __future__ import annotations

import asyncio
import concurrent.futures.thread as _futures_thread
import datetime as _dt
import io
import math
import os
import queue as _queue
import selectors
import signal
import sys
import threading
import time
from asyncio import unix_events
from collections.abc import Callable, Mapping
from itertools import islice
from typing import Any

from harness.core.clock import NS_PER_S
from harness.simclock import iowait, threads
from harness.simclock.installed import INSTALLED
from harness.simclock.runtime import SimRuntime
from harness.simclock.threads import Kind, Waiter

_originals: dict[tuple[object, str], Any] = {}
_SIM_CLOCKS = ("CLOCK_MONOTONIC", "CLOCK_MONOTONIC_RAW", "CLOCK_MONOTONIC_COARSE", "CLOCK_BOOTTIME", "CLOCK_UPTIME")
_WALL_CLOCKS = ("CLOCK_REALTIME", "CLOCK_REALTIME_COARSE", "CLOCK_TAI")


def _set(owner: object, name: str, value: object) -> None:
    key = (owner, name)
    if key not in _originals:
        _originals[key] = getattr(owner, name)
    setattr(owner, name, value)


def installed() -> bool:
    return INSTALLED.runtime is not None


def install(rt: SimRuntime) -> None:
    """Patch the process so that time and waits follow ``rt``."""
    if INSTALLED.runtime is rt:
        return
    if INSTALLED.runtime is not None:
        uninstall()
    INSTALLED.runtime = rt

    read = rt.clock_read  # a thread that keeps reading the clock without waiting waits for time to pass

    def sim_time() -> float:
        read()
        return rt.unix_ns() / NS_PER_S

    def sim_time_ns() -> int:
        read()
        return rt.unix_ns()

    def sim_mono() -> float:
        read()
        return rt.now_ns() / NS_PER_S

    def sim_mono_ns() -> int:
        read()
        return rt.now_ns()

    def sim_sleep(seconds: float) -> None:
        if seconds < 0:
            raise ValueError("sleep length must be non-negative")
        rt.sleep_ns(round(seconds * NS_PER_S))

    sim_clocks = {getattr(time, n) for n in _SIM_CLOCKS if hasattr(time, n)}
    wall_clocks = {getattr(time, n) for n in _WALL_CLOCKS if hasattr(time, n)}
    clock_gettime_ns = time.clock_gettime_ns

    def sim_clock_gettime_ns(clock_id: int) -> int:
        """Raw clock reads: the monotonic clocks read sim time, the wall clocks the run's epoch plus sim time (as
        ``simtime.c`` gives C code); CPU-time clocks stay real."""
        if clock_id in sim_clocks:
            return sim_mono_ns()
        if clock_id in wall_clocks:
            return sim_time_ns()
        return clock_gettime_ns(clock_id)

    def sim_clock_gettime(clock_id: int) -> float:
        return sim_clock_gettime_ns(clock_id) / NS_PER_S

    for name, fn in {
        "clock_gettime": sim_clock_gettime,
        "clock_gettime_ns": sim_clock_gettime_ns,
        "time": sim_time,
        "time_ns": sim_time_ns,
        "monotonic": sim_mono,
        "monotonic_ns": sim_mono_ns,
        "perf_counter": sim_mono,
        "perf_counter_ns": sim_mono_ns,
        "sleep": sim_sleep,
    }.items():
        _set(time, name, fn)

    def wait_clock() -> float:
        # the clock of timed waits: sim time where waits are sim-time waits, real time elsewhere
        return (rt.now_ns() if rt.on_sim_time() else rt.wall.now_ns()) / NS_PER_S

    # modules that captured a time function at import, for their timed waits
    _set(threading, "_time", wait_clock)
    _set(_queue, "time", wait_clock)

    _set(_dt, "datetime", _make_datetime(rt))
    _set(_dt, "date", _make_date(rt))

    for name, fn in _signal_timers(rt).items():
        _set(signal, name, fn)

    _set(threading.Condition, "wait", _make_condition_wait(rt))
    _set(threading.Condition, "notify", _make_condition_notify(rt))
    _set(_futures_thread.ThreadPoolExecutor, "__init__", _make_executor_init())

    for (owner, name), value in (iowait.patches(rt) | threads.patches(rt)).items():
        _set(owner, name, value)
    rt.threads.adopt_main()
    stdin = _idle_stdin(rt, sys.stdin)
    if stdin is not None:
        _set(sys, "stdin", stdin)

    loop_cls = _make_loop_class(rt)
    policy_cls = type("SimEventLoopPolicy", (asyncio.DefaultEventLoopPolicy,), {"_loop_factory": loop_cls})
    _set(asyncio, "SelectorEventLoop", loop_cls)
    _set(unix_events, "SelectorEventLoop", loop_cls)
    _originals.setdefault((asyncio, "_policy"), asyncio.get_event_loop_policy())
    asyncio.set_event_loop_policy(policy_cls())


def uninstall() -> None:
    """Put every original back."""
    if INSTALLED.runtime is None:
        return
    policy = _originals.pop((asyncio, "_policy"), None)
    for (owner, name), value in reversed(list(_originals.items())):
        setattr(owner, name, value)
    _originals.clear()
    asyncio.set_event_loop_policy(policy)
    INSTALLED.runtime = None


def patched_names() -> Mapping[str, str]:
    """What is patched now (for tests and ``docs/simclock.md``)."""
    return {f"{getattr(o, '__name__', o)}.{n}": repr(v) for (o, n), v in _originals.items()}


# --- signal timers ---------------------------------------------------------------------------------


def _signal_timers(rt: SimRuntime) -> dict[str, Callable[..., Any]]:
    """``signal.setitimer(ITIMER_REAL, …)``, ``getitimer`` and ``alarm`` on sim time (``SimRuntime.set_itimer``):
    SIGALRM reaches the main thread at the first phase at or after the deadline. The CPU-time timers
    (``ITIMER_VIRTUAL``, ``ITIMER_PROF``) stay real."""
    setitimer, getitimer = signal.setitimer, signal.getitimer

    def to_s(pair: tuple[int, int]) -> tuple[float, float]:
        return pair[0] / NS_PER_S, pair[1] / NS_PER_S

    def sim_setitimer(which: int, seconds: float, interval: float = 0.0) -> tuple[float, float]:
        if which != signal.ITIMER_REAL:
            return setitimer(which, seconds, interval)
        if seconds < 0 or interval < 0:
            return setitimer(which, seconds, interval)  # Python's own error
        return to_s(rt.set_itimer(round(seconds * NS_PER_S), round(interval * NS_PER_S)))

    def sim_getitimer(which: int) -> tuple[float, float]:
        if which != signal.ITIMER_REAL:
            return getitimer(which)
        return to_s(rt.get_itimer())

    def sim_alarm(seconds: int) -> int:
        left, _ = rt.set_itimer(int(seconds) * NS_PER_S, 0)
        return math.ceil(left / NS_PER_S) if left else 0

    return {"setitimer": sim_setitimer, "getitimer": sim_getitimer, "alarm": sim_alarm}


# --- thread pools --------------------------------------------------------------------------------


DEFAULT_POOL_WORKERS = 32
"""Workers of a pool made without ``max_workers`` (the event loop's default executor among them) in a mission:
Python's own default, ``min(32, cpu_count + 4)``, depends on the machine, and with it when a script's blocking
calls beyond that many start (6 on 2 cores: a swarm script's seventh ``System`` connected a phase later)."""


class _PoolQueue(_queue.Queue[Any]):
    """A thread pool's work queue that knows how many workers wait on it: ``waiting`` counts the threads inside
    :meth:`get`, under the queue's own lock. Its waits are ``Condition`` waits, so sim-time waits: a worker
    waiting for work is idle, and ``put`` marks it busy as it hands the work over (``Condition.notify``), so the
    work runs in this phase (the pool's own ``SimpleQueue`` is C: a worker woken from it ran whenever the machine
    scheduled it, maybe after phase 0 had ended)."""

    def __init__(self) -> None:
        super().__init__()
        self.waiting = 0

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        if not block or timeout is not None:
            return super().get(block, timeout)
        with self.not_empty:
            self.waiting += 1
            try:
                while not self._qsize():
                    self.not_empty.wait()
            finally:
                self.waiting -= 1
            item = self._get()
            self.not_full.notify()
            return item

    def has_worker_for_each(self) -> bool:
        """Whether a worker waits in :meth:`get` for every queued item."""
        with self.mutex:
            return self._qsize() <= self.waiting


class _IdleWorkers:
    """The pool's ``_idle_semaphore``, exact: ``acquire(timeout=0)`` (after ``submit`` queued its work) says
    "a worker waits for it" only when as many workers wait in ``get`` as items are queued.

    CPython's semaphore is released after every work item, also by a worker that goes on to the next queued
    item without waiting: it then counts workers that are busy, ``submit`` starts no thread, and the work waits
    behind calls that block (a MAVSDK ``first_autopilot``) for as many phases as they do, in some runs and not
    in others. Counted exactly, a submitted item starts in the phase it was submitted in whenever fewer than
    ``max_workers`` items run, whatever the threads' order (a worker about to come back may make one thread too
    many, never one too few)."""

    def __init__(self, work: _PoolQueue) -> None:
        self._work = work

    def acquire(self, blocking: bool = True, timeout: float | None = None) -> bool:
        return self._work.has_worker_for_each()

    def release(self, n: int = 1) -> None:
        """A worker finished an item: it is counted when it waits in ``get``, not now."""


def _make_executor_init() -> Callable[..., None]:
    """Pools hand work over exactly (:class:`_PoolQueue`, :class:`_IdleWorkers`), with a machine-independent
    default size (:data:`DEFAULT_POOL_WORKERS`)."""
    orig = _futures_thread.ThreadPoolExecutor.__init__

    def __init__(self: Any, max_workers: int | None = None, *args: Any, **kwargs: Any) -> None:
        orig(self, DEFAULT_POOL_WORKERS if max_workers is None else max_workers, *args, **kwargs)
        self._work_queue = work = _PoolQueue()
        self._idle_semaphore = _IdleWorkers(work)

    return __init__


# --- stdin ---------------------------------------------------------------------------------------
class _IdleReader(io.RawIOBase):
    """A descriptor whose blocking reads are sim-time waits without a deadline: a script waiting for a line
    (``harness run --stdin``) counts as idle, so the simulation goes on meanwhile; at end-of-file (the
    mission's stdin without ``--stdin``) a read returns at once."""

    def __init__(self, rt: SimRuntime, fd: int) -> None:
        super().__init__()
        self._rt = rt
        self._fd = fd

    def readable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._fd

    def readinto(self, b: Any) -> int:
        while not iowait.real_select([self._fd], [], [], 0)[0]:
            iowait.wait(self._rt, [self._fd])
        data = os.read(self._fd, len(b))
        b[: len(data)] = data
        return len(data)


def _idle_stdin(rt: SimRuntime, stdin: Any) -> io.TextIOWrapper | None:
    try:
        fd = stdin.fileno()
    except (AttributeError, OSError, ValueError):
        return None  # no real descriptor (a test's replacement): leave it
    enc, errors = getattr(stdin, "encoding", None) or "utf-8", getattr(stdin, "errors", None) or "strict"
    return io.TextIOWrapper(io.BufferedReader(_IdleReader(rt, fd)), encoding=enc, errors=errors)


# --- datetime ------------------------------------------------------------------------------------


def _make_datetime(rt: SimRuntime) -> type:
    base = _dt.datetime

    class datetime(base):  # type: ignore[valid-type,misc]
        @classmethod
        def now(cls, tz: _dt.tzinfo | None = None) -> Any:
            return cls.fromtimestamp(rt.unix_ns() / NS_PER_S, tz)

        @classmethod
        def utcnow(cls) -> Any:
            return cls.fromtimestamp(rt.unix_ns() / NS_PER_S, _dt.UTC).replace(tzinfo=None)

        @classmethod
        def today(cls) -> Any:
            return cls.fromtimestamp(rt.unix_ns() / NS_PER_S)

    datetime.__module__ = "datetime"
    return datetime


def _make_date(rt: SimRuntime) -> type:
    base = _dt.date

    class date(base):  # type: ignore[valid-type,misc]
        @classmethod
        def today(cls) -> Any:
            return cls.fromtimestamp(rt.unix_ns() / NS_PER_S)

    date.__module__ = "datetime"
    return date


# --- threading --------------------------------------------------------------------------------------


def _make_condition_wait(rt: SimRuntime) -> Callable[..., bool]:
    original = threading.Condition.wait

    def wait(self: Any, timeout: float | None = None) -> bool:
        if not rt.on_sim_time():
            return original(self, timeout)
        if not self._is_owned():
            raise RuntimeError("cannot wait on un-acquired lock")
        waiter = threading._allocate_lock()  # type: ignore[attr-defined]
        waiter.acquire()
        self._waiters.append(waiter)
        if timeout is not None and timeout <= 0:
            saved = self._release_save()
            got = waiter.acquire(False)
            self._acquire_restore(saved)
            if not got:
                _remove(self._waiters, waiter)
            return bool(got)
        deadline = None if timeout is None else rt.now_ns() + round(timeout * NS_PER_S)
        w: Waiter = rt.new_waiter(Kind.CONDITION, deadline_ns=deadline, lock=waiter)
        saved = self._release_save()
        try:
            waiter.acquire()
        finally:
            rt.finish_wait(w)
            self._acquire_restore(saved)
        if w.timed_out:
            _remove(self._waiters, waiter)
            return False
        return True

    return wait


def _make_condition_notify(rt: SimRuntime) -> Callable[..., None]:
    def notify(self: Any, n: int = 1) -> None:
        if not self._is_owned():
            raise RuntimeError("cannot notify on un-acquired lock")
        all_waiters = self._waiters
        for waiter in list(islice(all_waiters, n)):
            if not rt.release(waiter):
                try:
                    waiter.release()
                except RuntimeError:
                    pass
            _remove(all_waiters, waiter)

    return notify


def _remove(waiters: Any, waiter: object) -> None:
    try:
        waiters.remove(waiter)
    except ValueError:
        pass


# --- asyncio ----------------------------------------------------------------------------------------


class SimSelector(selectors.BaseSelector):
    """A selector whose blocking waits count as idle and end on sim deadlines, not wall timeouts."""

    def __init__(self, rt: SimRuntime, inner: selectors.BaseSelector) -> None:
        self._rt = rt
        self._inner = inner
        self.wake: Callable[[], None] | None = None
        self.timers_held = False
        """Set by the loop for each ``select``: it asks for no wait only because a timer held for the phase's second
        round is due (``SimRuntime.timers_held``), so wait for that round (or for I/O)."""

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._inner.register(fileobj, events, data)

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        return self._inner.unregister(fileobj)

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._inner.modify(fileobj, events, data)

    def get_key(self, fileobj: Any) -> selectors.SelectorKey:
        return self._inner.get_key(fileobj)

    def get_map(self) -> Mapping[Any, selectors.SelectorKey]:
        return self._inner.get_map()

    def close(self) -> None:
        self._inner.close()

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        rt = self._rt
        if not rt.on_sim_time():
            return self._inner.select(timeout)
        if timeout is not None and timeout <= 0:
            if not self.timers_held:
                rt.clock_read()  # a loop that is never idle (``await asyncio.sleep(0)`` forever) sees time pass
                return self._inner.select(timeout)
            deadline: int | None = rt.now_ns()  # a timer is due: it runs in the phase's second round
        else:
            deadline = None if timeout is None else rt.now_ns() + max(1, round(timeout * NS_PER_S))
        events = self._inner.select(0)
        if events:
            return events
        # the epoll descriptor itself: the clock thread sees the loop's I/O (and its self-pipe, written by a
        # MAVSDK thread's call_soon_threadsafe) before it decides that phase 0 is over
        fileno = getattr(self._inner, "fileno", None)
        w = rt.new_waiter(
            Kind.LOOP, deadline_ns=deadline, wake=self.wake, rfds=(fileno(),) if fileno is not None else ()
        )
        events = self._inner.select(None)
        if rt.loop_woken(w):
            return events
        # I/O arrived outside phase 0: leave it in the kernel until the gate opens
        rt.wait_gate()
        return self._inner.select(0)


def _raw_selector() -> selectors.BaseSelector:
    """A selector that waits on the wall clock (``SimSelector`` turns its waits into sim-time waits)."""
    return iowait.RawEpollSelector() if iowait.real_epoll is not None else selectors.SelectSelector()


def _make_loop_class(rt: SimRuntime) -> type[asyncio.AbstractEventLoop]:
    base: type[Any] = unix_events._UnixSelectorEventLoop

    resolution = time.get_clock_info("monotonic").resolution  # asyncio's own _clock_resolution

    class SimEventLoop(base):
        """The default loop with sim time: timers and timeouts follow the simulation clock."""

        def __init__(self, selector: selectors.BaseSelector | None = None) -> None:
            sel = SimSelector(rt, selector or _raw_selector())
            super().__init__(sel)
            sel.wake = self._write_to_self

        def time(self) -> float:
            return rt.now_ns() / NS_PER_S

        def _run_once(self) -> None:
            """One iteration of the loop; in a phase's first round its due timers wait for the second
            (``SimRuntime.timers_held``): no timer is moved to the ready queue (an end time of -inf), and a
            ``select`` that would not wait only because of them waits for that round."""
            held = rt.timers_held() and rt.on_sim_time()
            self._selector.timers_held = held and not self._ready and not self._stopping
            self._clock_resolution = -math.inf if held else resolution
            super()._run_once()

    return SimEventLoop
