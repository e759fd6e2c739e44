"""What many tests need, in one place: waiting for a condition on the wall clock, a free TCP port, two hosts
(network namespaces) for runs spread over machines.

(Process-level rigs stay next to the tests that use them: ``tests/channel/rig.py``, ``tests/autopilot/rig.py``,
``tests/autopilot/mavlink/conftest.py``, ``tests/simclock/conftest.py``.)
"""

from __future__ import annotations

import subprocess
import sys
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TypeVar

from harness.core.clock import real_monotonic_ns, real_sleep
from harness.core.freeport import free_tcp_port

T = TypeVar("T")

__all__ = ["TwoHosts", "free_port_on", "free_tcp_port", "two_hosts", "wait_until"]


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


def _ip(*args: str) -> bool:
    return subprocess.run(["ip", *args], capture_output=True).returncode == 0


@dataclass(frozen=True)
class TwoHosts:
    """Two hosts for a run spread over machines: network namespaces joined by a veth pair, or (no CAP_NET_ADMIN)
    this machine's loopback addresses."""

    a_ip: str
    b_ip: str
    a_prefix: tuple[str, ...]
    """Command prefix that runs a process on host a (``ip netns exec NS``, or nothing)."""
    b_prefix: tuple[str, ...]
    isolated: bool
    """Whether they are namespaces of their own."""


@contextmanager
def two_hosts(subnet: str, loopback: tuple[str, str]) -> Iterator[TwoHosts]:
    """Namespaces with ``subnet``.1 and ``subnet``.2 (e.g. ``10.231.0``), removed afterwards; without the
    right to make them, the ``loopback`` addresses on this machine."""
    tag = uuid.uuid4().hex[:6]
    a, b = f"ha-{tag}", f"hb-{tag}"
    made = _ip("netns", "add", a) and _ip("netns", "add", b)
    if made:
        made = all(
            _ip(*cmd)
            for cmd in (
                ("link", "add", f"va{tag}", "type", "veth", "peer", "name", f"vb{tag}"),
                ("link", "set", f"va{tag}", "netns", a),
                ("link", "set", f"vb{tag}", "netns", b),
                ("-n", a, "addr", "add", f"{subnet}.1/24", "dev", f"va{tag}"),
                ("-n", b, "addr", "add", f"{subnet}.2/24", "dev", f"vb{tag}"),
                ("-n", a, "link", "set", f"va{tag}", "up"),
                ("-n", b, "link", "set", f"vb{tag}", "up"),
                ("-n", a, "link", "set", "lo", "up"),
                ("-n", b, "link", "set", "lo", "up"),
            )
        )
    try:
        if made:
            yield TwoHosts(f"{subnet}.1", f"{subnet}.2", ("ip", "netns", "exec", a), ("ip", "netns", "exec", b), True)
        else:
            yield TwoHosts(*loopback, (), (), False)
    finally:
        _ip("netns", "del", a)
        _ip("netns", "del", b)


def free_port_on(prefix: tuple[str, ...], ip: str) -> int:
    """A free TCP port on ``ip`` as seen from the host ``prefix`` runs on."""
    code = f"import socket; s = socket.socket(); s.bind(({ip!r}, 0)); print(s.getsockname()[1])"
    out = subprocess.run([*prefix, sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout)
