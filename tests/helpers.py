"""What many tests need, in one place: waiting for a condition on the wall clock, a free TCP port.

(Process-level rigs stay next to the tests that use them: ``tests/channel/rig.py``, ``tests/autopilot/rig.py``,
``tests/autopilot/mavlink/conftest.py``, ``tests/simclock/conftest.py``.)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from harness.core.clock import real_monotonic_ns, real_sleep
from harness.core.freeport import free_tcp_port

T = TypeVar("T")

__all__ = ["free_tcp_port", "wait_until"]


def wait_until(cond: Callable[[], T], timeout_s: float = 20.0, what: str = "condition", poll_s: float = 0.02) -> T:
    """Poll ``cond`` until it returns something true and return that; AssertionError naming ``what`` after
    ``timeout_s`` of wall time (the real clock: a test may run with time patched)."""
    end = real_monotonic_ns() + round(timeout_s * 1e9)
    while True:
        value = cond()
        if value:
            return value
        if real_monotonic_ns() > end:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        real_sleep(poll_s)
