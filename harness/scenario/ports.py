"""Port allocation for a run: parallel runs on one machine never collide.

A run needs, per vehicle ``i``, the UDP port its mission (MAVSDK) listens on (``api_base + i``), and one
GCS port. The standard ports (14540+i, 14550: what PX4 SITL users and QGroundControl expect) are used
when they are all free; otherwise a free block is chosen. A block is *held* (sockets bound with
SO_REUSEADDR off) until the run's processes bind it themselves, which closes the race between two
``harness run`` started at the same moment as far as one machine allows: the second one sees the
block taken and picks another. Fallback blocks lie below the kernel's ephemeral port range, so no
socket bound to port 0 (ours or anyone's) can take one of them in the moment between release and bind.
"""

from __future__ import annotations

import contextlib
import random
import socket
from dataclasses import dataclass, field
from pathlib import Path

from harness.errors import SimulationError


@dataclass
class PortBlock:
    api_base: int
    gcs: int
    _held: list[socket.socket] = field(default_factory=list, repr=False)

    def release(self) -> None:
        """Let the run's own processes bind the ports."""
        for s in self._held:
            with contextlib.suppress(OSError):
                s.close()
        self._held.clear()


def _hold(ports: list[int]) -> list[socket.socket] | None:
    held: list[socket.socket] = []
    for port in ports:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            s.close()
            for h in held:
                h.close()
            return None
        held.append(s)
    return held


def ephemeral_range() -> tuple[int, int]:
    """The kernel's range for automatically assigned ports (Linux: /proc; elsewhere the IANA range)."""
    try:
        lo, hi = (int(x) for x in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
        return lo, hi
    except (OSError, ValueError):
        return 49152, 65535


def _free_span(vehicles: int) -> tuple[int, int]:
    """Where to look for a block: below the ephemeral range. Every socket bound to port 0 (the autopilots'
    senders, mavsdk_server's gRPC port, other programs) gets a port from that range, so a block inside it
    can be taken between our release and the mission's bind (seen with 50 vehicles: "Bind error")."""
    lo, _ = ephemeral_range()
    top = min(lo, 65536) - vehicles - 2
    if top - 10000 < 1000:  # an unusually wide ephemeral range: fall back to the old span
        return 20000, 60000 - vehicles - 2
    return 10000, top


def allocate(vehicles: int, api_base: int = 14540, gcs: int = 14550, rng: random.Random | None = None) -> PortBlock:
    """The standard ports when free, else a free block below the kernel's ephemeral port range."""
    standard = [api_base + i for i in range(vehicles)] + ([gcs] if gcs else [])
    if len(set(standard)) == len(standard):
        held = _hold(standard)
        if held is not None:
            return PortBlock(api_base, gcs, held)
    rng = rng or random.Random()
    span_lo, span_hi = _free_span(vehicles)
    for _ in range(200):
        base = rng.randrange(span_lo, span_hi)
        ports = [base + i for i in range(vehicles)] + [base + vehicles]
        held = _hold(ports)
        if held is not None:
            return PortBlock(base, base + vehicles, held)
    raise SimulationError(f"no block of {vehicles + 1} free UDP ports on 127.0.0.1 after 200 tries")
