"""``--speed X`` as a rate: X seconds of sim per second of wall time, from wherever the run is now.

The run is paced against a schedule (sim time ``t`` is due at ``origin + t / X`` of wall time): a tick that
is early waits for its time, a short lag — a busy machine, a garbage collection — is made up by running
faster for a moment. A longer stall (the process stopped with SIGSTOP and continued, a laptop that slept, a
debugger) is not made up: the schedule moves so that the run goes on at X from where it is, instead of racing
at full speed until it is back on its original schedule.
"""

from __future__ import annotations

from harness.core.clock import NS_PER_S

MAX_LAG_NS = NS_PER_S // 2
"""The longest lag (wall time) that is made up; beyond it the schedule moves."""


class Pacer:
    """When each tick is due. Pure: the caller reads the clock and sleeps."""

    def __init__(self, speed: float, start_ns: int, max_lag_ns: int = MAX_LAG_NS) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.speed = speed
        self.origin_ns = start_ns
        """The wall time at which sim time 0 is (was, or would have been) due."""
        self.max_lag_ns = max_lag_ns
        self.moved_ns = 0
        """How far the schedule has moved, in all: stalls that were not made up."""
        self.behind_ns = 0
        """Of that, how far because the run could not keep up (lags beyond ``max_lag_ns``; pauses not counted)."""

    def wait_ns(self, t_ns: int, now_ns: int) -> int:
        """How long to wait before the tick at sim time ``t_ns`` (0 when it is due or late)."""
        lag = now_ns - (self.origin_ns + int(t_ns / self.speed))
        if lag > self.max_lag_ns:
            self.shift(lag - self.max_lag_ns)
            self.behind_ns += lag - self.max_lag_ns
            lag = self.max_lag_ns
        return max(0, -lag)

    def lag_ns(self, t_ns: int, now_ns: int) -> int:
        """How late sim time ``t_ns`` is at ``now_ns`` against the schedule (0 when on time or early)."""
        return max(0, now_ns - (self.origin_ns + int(t_ns / self.speed)))

    def shift(self, wall_ns: int) -> None:
        """Move the schedule ``wall_ns`` later (a pause: nothing of it is made up)."""
        self.origin_ns += wall_ns
        self.moved_ns += wall_ns
