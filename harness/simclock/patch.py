"""Reversible patching of time in a mission process: ``time``, ``datetime``, threading waits, asyncio.

:func:`install` replaces, for the whole process, everything in the table of ``docs/simclock.md`` with
versions that read or wait on the :class:`~harness.simclock.runtime.SimRuntime`; :func:`uninstall`
puts every original back. Installing twice is a no-op; so is uninstalling when nothing is installed.
"""

from __future__ import annotations

import asyncio
import concurrent.futures.thread as _futures_thread
import datetime as _dt
import queue as _queue
import selectors
import threading
import time
from asyncio import unix_events
from collections.abc import Callable, Mapping
from itertools import islice
from typing import Any

from harness.core.clock import NS_PER_S
from harness.simclock import iowait
from harness.simclock.installed import INSTALLED
from harness.simclock.runtime import SimRuntime, Waiter

_originals: dict[tuple[object, str], Any] = {}


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

    for name, fn in {
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
        return (rt.now_ns() if rt._tracked() else rt.wall.now_ns()) / NS_PER_S

    # modules that captured a time function at import, for their timed waits
    _set(threading, "_time", wait_clock)
    _set(_queue, "time", wait_clock)

    _set(_dt, "datetime", _make_datetime(rt))
    _set(_dt, "date", _make_date(rt))

    _set(threading.Condition, "wait", _make_condition_wait(rt))
    _set(threading.Condition, "notify", _make_condition_notify(rt))
    _set(_futures_thread.ThreadPoolExecutor, "__init__", _make_executor_init())

    for (owner, name), value in iowait.patches(rt).items():
        _set(owner, name, value)

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


# --- thread pools --------------------------------------------------------------------------------


def _make_executor_init() -> Callable[..., None]:
    """Thread-pool workers wait for work on a ``queue.Queue``, whose waits are sim-time waits: a worker waiting
    for work is idle, and ``submit`` marks it busy as it hands the work over (``Condition.notify``), so the work
    runs in this phase. The pool's own ``SimpleQueue`` is C: a worker woken from it ran whenever the machine
    scheduled it, maybe after phase 0 had ended (a MAVSDK request in ``run_in_executor`` went out a phase late
    in one run of six)."""
    orig = _futures_thread.ThreadPoolExecutor.__init__

    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
        orig(self, *args, **kwargs)
        self._work_queue = _queue.Queue()

    return __init__


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
        if not rt._tracked():
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
        w: Waiter = rt.new_waiter(deadline_ns=deadline, lock=waiter)
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
        if not rt._tracked():
            return self._inner.select(timeout)
        if timeout is not None and timeout <= 0:
            rt.clock_read()  # a loop that is never idle (``await asyncio.sleep(0)`` forever) sees time pass
            return self._inner.select(timeout)
        events = self._inner.select(0)
        if events:
            return events
        deadline = None if timeout is None else rt.now_ns() + max(1, round(timeout * NS_PER_S))
        # the epoll descriptor itself: the clock thread sees the loop's I/O (and its self-pipe, written by a
        # MAVSDK thread's call_soon_threadsafe) before it decides that phase 0 is over
        fileno = getattr(self._inner, "fileno", None)
        w = rt.new_waiter(deadline_ns=deadline, wake=self.wake, rfds=(fileno(),) if fileno is not None else ())
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

    class SimEventLoop(base):
        """The default loop with sim time: timers and timeouts follow the simulation clock."""

        def __init__(self, selector: selectors.BaseSelector | None = None) -> None:
            sel = SimSelector(rt, selector or _raw_selector())
            super().__init__(sel)
            sel.wake = self._write_to_self

        def time(self) -> float:
            return rt.now_ns() / NS_PER_S

    return SimEventLoop
