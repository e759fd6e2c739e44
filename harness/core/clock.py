"""One clock abstraction: integer nanoseconds inside; a wall, a manual and a simulated implementation.

Library code never calls ``time.*`` directly: it is given a :class:`Clock` (``WALL`` by default) and reads
and waits on that, so the same code runs on real time, on a test's :class:`ManualClock`, or on a mission
process's sim clock (``harness.simclock.runtime.SimRuntime`` is one). The real time functions are
captured here at import, before a mission process patches the ``time`` module, so the wall clock keeps
reading real time inside a patched process.
"""

from __future__ import annotations

import time as _time
from typing import Final, Protocol

NS_PER_S: Final = 1_000_000_000

real_monotonic_ns = _time.monotonic_ns
real_time_ns = _time.time_ns
real_perf_counter_ns = _time.perf_counter_ns
real_sleep = _time.sleep


class Clock(Protocol):
    """Where time is read and waited on (as trio's ``Clock``; integer nanoseconds)."""

    def now_ns(self) -> int:
        """Monotonic time: only differences mean anything."""
        ...

    def unix_ns(self) -> int:
        """The date, as nanoseconds since the Unix epoch (log stamps, MAVLink signing timestamps)."""
        ...

    def sleep_ns(self, ns: int) -> None:
        """Block the calling thread for ``ns`` of this clock's time (``ns <= 0`` returns at once)."""
        ...


class WallClock:
    """Real time: the monotonic clock, the system date, a real sleep."""

    __slots__ = ()

    # the C functions themselves: reading the wall clock costs no Python frame on the hot paths
    now_ns = staticmethod(real_monotonic_ns)
    unix_ns = staticmethod(real_time_ns)

    def sleep_ns(self, ns: int) -> None:
        real_sleep(max(0, ns) / NS_PER_S)  # sleep(0) still yields the processor, as time.sleep(0) does


WALL: Final = WallClock()
"""The wall clock (stateless: one instance serves everyone); the default wherever a clock is injected."""


class ManualClock:
    """Time that only moves when told to (tests): ``advance``/``advance_to``, or a ``sleep_ns`` that jumps
    the clock forward by the sleep instead of waiting (trio's ``MockClock`` with autojump). Never goes
    backwards."""

    def __init__(self, start_ns: int = 0, epoch_unix_ns: int = 0) -> None:
        self._now = start_ns
        self._epoch = epoch_unix_ns

    def now_ns(self) -> int:
        return self._now

    def unix_ns(self) -> int:
        return self._epoch + self._now

    def sleep_ns(self, ns: int) -> None:
        if ns > 0:
            self._now += ns

    def advance(self, ns: int) -> None:
        if ns < 0:
            raise ValueError(f"time cannot go backwards (advance by {ns} ns)")
        self._now += ns

    def advance_to(self, t_ns: int) -> None:
        if t_ns < self._now:
            raise ValueError(f"time cannot go backwards ({t_ns} ns < {self._now} ns)")
        self._now = t_ns


def s_to_ns(seconds: float) -> int:
    return round(seconds * NS_PER_S)


def ns_to_s(ns: int) -> float:
    return ns / NS_PER_S
