"""The channel's watchdog: a deadline per awaited peer, read from an injected clock.

The tick machine says *whom* it waits for and for how long (``watch``); the watchdog turns that into a
deadline on its :class:`~harness.core.clock.Clock`, tells the shell how long it may block
(``timeout_s``) and which waits ran out (``expired``). A channel runs it on the wall clock; tests run it
on a :class:`~harness.core.clock.ManualClock` and move time by hand.
"""

from __future__ import annotations

from typing import Final

from harness.core.clock import NS_PER_S, Clock

JOIN: Final = -1
"""The key of the wait for autopilots of vehicles that physics simulates but nobody holds yet."""


class Watchdog:
    """Deadlines by key (a peer id, or :data:`JOIN`) on ``clock``."""

    __slots__ = ("_clock", "_deadlines")

    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self._deadlines: dict[int, int] = {}

    def now_ns(self) -> int:
        return self._clock.now_ns()

    def deadline(self, limit_s: float) -> int:
        """The deadline ``limit_s`` from now (one reading of the clock for many ``arm`` calls)."""
        return self._clock.now_ns() + int(limit_s * NS_PER_S)

    def arm(self, key: int, deadline_ns: int) -> None:
        self._deadlines[key] = deadline_ns

    def watch(self, key: int, limit_s: float) -> None:
        """Expect an answer from ``key`` within ``limit_s``."""
        self._deadlines[key] = self.deadline(limit_s)

    def watching(self, key: int) -> bool:
        return key in self._deadlines

    def clear(self, key: int) -> None:
        self._deadlines.pop(key, None)

    def next_deadline_ns(self) -> int | None:
        return min(self._deadlines.values()) if self._deadlines else None

    def timeout_s(self) -> float | None:
        """How long the shell may block before a deadline runs out (None: no deadline at all)."""
        earliest = self.next_deadline_ns()
        if earliest is None:
            return None
        return max(0.0, (earliest - self._clock.now_ns()) / NS_PER_S)

    def expired(self) -> list[int]:
        """The keys whose deadline has passed, earliest first; they stay armed until cleared."""
        deadlines = self._deadlines
        if not deadlines:
            return []
        now = self._clock.now_ns()
        if now < min(deadlines.values()):  # the usual answer, asked after every wait: without sorting them
            return []
        return [k for k, d in sorted(deadlines.items(), key=lambda kv: kv[1]) if now >= d]
