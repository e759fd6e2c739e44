"""One clock abstraction: integer nanoseconds inside, a wall and a simulated implementation.

Library code never calls ``time.*`` directly. The real time functions are captured here at import,
before any mission process patches the ``time`` module, so the harness's own machinery (watchdogs,
wall-clock MAVLink timers, real-time pacing) keeps reading the real clock inside a patched process.
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
    """Anything that tells the current time in integer nanoseconds."""

    def now_ns(self) -> int: ...


class WallClock:
    """Real (monotonic) time since the clock was made."""

    def __init__(self) -> None:
        self._start = real_monotonic_ns()

    def now_ns(self) -> int:
        return real_monotonic_ns() - self._start


class ManualClock:
    """Simulated time that only moves when told to; refuses to go backwards."""

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns

    def now_ns(self) -> int:
        return self._now

    def advance_to(self, t_ns: int) -> None:
        if t_ns < self._now:
            raise ValueError(f"simulated time cannot go backwards ({t_ns} ns < {self._now} ns)")
        self._now = t_ns


def s_to_ns(seconds: float) -> int:
    return round(seconds * NS_PER_S)


def ns_to_s(ns: int) -> float:
    return ns / NS_PER_S
