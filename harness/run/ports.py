"""Port allocation for a run: parallel runs on one machine never share a port.

A run needs, per vehicle ``i``, the UDP port its autopilot listens on for its mission (``api_base + i``;
the mission connects *out* to it, as a script does to PX4 SITL's 14580), and one GCS port its vehicles
send to. PX4 SITL's ports (14580+i, and 14550 for the ground station) are used when they are free;
otherwise a free block is chosen.

The GCS port is a destination, as PX4 SITL's and MAVProxy's outputs are: ``harness sitl``'s vehicles send
to 14550 whether or not a ground station listens there, and one that listens before the run starts
(QGroundControl opened first) hears them. Only another harness run holding it moves a run to a port of its
own. A batch run sends to a port of its own block unless told one (``[mavlink] gcs_port``): every run's
vehicle 0 is system 1, and a ground station on 14550 could command every batch run on the machine.

A block belongs to a run from allocation to the end of the run: every port of it is locked with an
advisory ``flock`` on a file per port (``<tmp>/uav-harness-ports-<uid>/<port>.lock``), held by an open
file of the run's process. Two ``harness run`` started in the same instant therefore never get the same
port, even for the ports that no process of the run binds (the GCS port belongs to whichever ground
station binds it), and a run that dies releases its locks with its process: nothing goes stale. Vehicle
ports another program has bound are skipped too (a probe bind with SO_REUSEADDR off). Fallback blocks lie below
the kernel's ephemeral port range, so that no socket bound to port 0 can take one of them.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from harness.core.endpoints import PX4_API_BASE
from harness.core.errors import SimulationError


@dataclass
class PortBlock:
    api_base: int
    gcs: int
    vehicles: int = 0
    _locks: list[IO[bytes]] = field(default_factory=list, repr=False)

    @property
    def ports(self) -> list[int]:
        return [self.api_base + i for i in range(self.vehicles)] + ([self.gcs] if self.gcs else [])

    def release(self) -> None:
        """Give the ports back (the end of the run; also done by the kernel when the process ends)."""
        for f in self._locks:
            with contextlib.suppress(OSError):
                f.close()
        self._locks.clear()

    def __enter__(self) -> PortBlock:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.release()


def lock_dir() -> Path:
    d = Path(tempfile.gettempdir()) / f"uav-harness-ports-{os.getuid()}"
    d.mkdir(mode=0o700, exist_ok=True)
    return d


def _lock(port: int) -> IO[bytes] | None:
    """An exclusive lock on ``port`` among harness runs (None: another run holds it)."""
    f = (lock_dir() / f"{port}.lock").open("ab")
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.close()
        return None
    return f


def _bindable(port: int) -> bool:
    """Whether no other program has bound UDP ``port`` on loopback (or on every address)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", port))
        return True
    except OSError:
        return False
    finally:
        s.close()


def _take(ports: list[int]) -> list[IO[bytes]] | None:
    locks: list[IO[bytes]] = []
    for port in ports:
        f = _lock(port)
        if f is None or not _bindable(port):
            if f is not None:
                f.close()
            for held in locks:
                held.close()
            return None
        locks.append(f)
    return locks


def ephemeral_range() -> tuple[int, int]:
    """The kernel's range for automatically assigned ports (Linux: /proc; elsewhere the IANA range)."""
    try:
        lo, hi = (int(x) for x in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
        return lo, hi
    except (OSError, ValueError):
        return 49152, 65535


def _free_span(size: int) -> tuple[int, int]:
    """Where to look for a block: below the ephemeral range. Every socket bound to port 0 (the autopilots'
    senders, mavsdk_server's gRPC port, other programs) gets a port from that range, so a block inside it
    can be taken by such a socket before the run binds it (seen with 50 vehicles: "Bind error")."""
    lo, _ = ephemeral_range()
    top = min(lo, 65536) - size - 1
    if top - 10000 < 1000:  # an unusually wide ephemeral range: fall back to the old span
        return 20000, 60000 - size - 1
    return 10000, top


def _free_block(size: int, rng: random.Random) -> tuple[int, list[IO[bytes]]]:
    """``size`` consecutive free ports below the kernel's ephemeral port range, locked."""
    span_lo, span_hi = _free_span(size)
    for _ in range(200):
        base = rng.randrange(span_lo, span_hi)
        locks = _take([base + i for i in range(size)])
        if locks is not None:
            return base, locks
    raise SimulationError(f"no block of {size} free UDP ports on 127.0.0.1 after 200 tries")


def allocate(
    vehicles: int, api_base: int = PX4_API_BASE, gcs: int | None = None, rng: random.Random | None = None
) -> PortBlock:
    """The standard ports when free, else a free block below the kernel's ephemeral port range; locked for
    this process until :meth:`PortBlock.release` or its end.

    The vehicles' own ports (``api_base + i``) must be free to bind. The ground station's port ``gcs`` is a
    destination: a ground station listening there (QGroundControl opened first) is what it is for, so only
    another harness run holding it moves this run to a port of its own. ``gcs = None``: a port of the run's
    own from the start (a batch run); 0: none."""
    rng = rng or random.Random()
    standard = [api_base + i for i in range(vehicles)]
    spare: int | None = None
    locks = _take(standard) if gcs not in standard else None
    base = api_base
    if locks is None:
        base, locks = _free_block(vehicles + 1, rng)
        spare = base + vehicles  # locked and bindable: the ground station port of this block
    if gcs == 0:
        return PortBlock(base, 0, vehicles, locks)
    held = _lock(gcs) if gcs is not None else None
    if gcs is not None and held is not None:
        return PortBlock(base, gcs, vehicles, [*locks, held])
    if spare is None:
        spare, more = _free_block(1, rng)
        locks += more
    return PortBlock(base, spare, vehicles, locks)
