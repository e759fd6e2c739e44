"""One wall-clock thread that serves the MAVLink servers of every vehicle in a process, without polling.

The thread sleeps in a single ``select()`` over every vehicle's UDP sockets and a wake-up pipe, and wakes
for exactly two reasons:

- a datagram arrived (commands are answered at once, on the wall clock);
- the earliest wall-clock deadline of any server: a stream on its wall rate, the 1 Hz heartbeat, a mission
  protocol retry, a paced parameter download.

Sim-rate telemetry and events are not its business: the autopilot's stepping thread serves them through
its bell (``Autopilot.attach_bell`` → ``MavlinkServer.service``) at the tick they fall due. So a paused or
slow simulation costs only the wall-rate telemetry and a fast one only its sim-rate telemetry, and N
vehicles cost one thread, not N threads waking at a fixed rate. (Before the hub, each vehicle had its own
thread checking every 10 ms of wall time: at 50 vehicles those threads took as much CPU as the physics and
autopilots together.)
"""

from __future__ import annotations

import contextlib
import enum
import logging
import os
import selectors
import threading
from collections import deque
from collections.abc import Sequence
from typing import Protocol

from harness.autopilot.mavlink.transport import Link
from harness.core.clock import WALL, Clock

log = logging.getLogger(__name__)

_OP_TIMEOUT_S = 5.0


class _Op(enum.Enum):
    ADD = "add"
    REMOVE = "remove"


class HubMember(Protocol):
    """What the hub uses of a server it serves (``harness.autopilot.mavlink.server.HubMember``)."""

    vehicle: int

    @property
    def links(self) -> Sequence[Link]: ...
    @property
    def next_wake_ns(self) -> int: ...
    def attached(self, hub: MavlinkHub) -> None: ...
    def receive(self, link: int, now: int) -> None: ...
    def service(self, now: int) -> None: ...


class MavlinkHub:
    """Serves any number of MAVLink servers (:class:`HubMember`) on one thread. ``add`` them, then ``start()``."""

    def __init__(self, name: str = "mavlink", clock: Clock = WALL) -> None:
        self.name = name
        self.clock = clock
        """The wall clock of its servers' deadlines (give each server the same)."""
        self._servers: dict[HubMember, None] = {}
        """In the order added (a dict: membership is tested for every server served)."""
        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        self._ops: deque[tuple[_Op, HubMember, threading.Event]] = deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    # ------------------------------------------------------------------ membership
    def add(self, server: HubMember) -> None:
        """Serve ``server`` (from any thread; applied by the hub thread when it runs)."""
        self._apply_or_queue(_Op.ADD, server)

    def remove(self, server: HubMember) -> None:
        """Stop serving ``server``; on return the hub no longer touches its sockets."""
        self._apply_or_queue(_Op.REMOVE, server)

    def _apply_or_queue(self, op: _Op, server: HubMember) -> None:
        thread = self._thread
        if thread is None or not thread.is_alive() or thread is threading.current_thread():
            self._apply(op, server)
            return
        done = threading.Event()
        self._ops.append((op, server, done))
        self._signal()
        if not done.wait(_OP_TIMEOUT_S):
            log.warning("%s: the hub thread did not %s vehicle %d in time", self.name, op.value, server.vehicle)

    def _apply(self, op: _Op, server: HubMember) -> None:
        if op is _Op.ADD:
            if server in self._servers:
                return
            self._servers[server] = None
            for i, link in enumerate(server.links):
                self._sel.register(link.sock, selectors.EVENT_READ, (server, i))
            server.attached(self)
        elif server in self._servers:
            del self._servers[server]
            for link in server.links:
                with contextlib.suppress(KeyError, ValueError, OSError):
                    self._sel.unregister(link.sock)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> MavlinkHub:
        if self._thread is not None:
            raise RuntimeError(f"{self.name}: already started")
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """End the thread (the servers' sockets stay open: each server closes its own)."""
        self._stop.set()
        self._signal()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        if not self._closed:
            self._closed = True
            self._sel.close()
            for fd in (self._wake_r, self._wake_w):
                with contextlib.suppress(OSError):
                    os.close(fd)

    def close(self) -> None:
        self.stop()

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive() and not self._stop.is_set()

    def _signal(self) -> None:
        with contextlib.suppress(OSError):  # a full pipe already wakes the thread; a closed one means stopped
            os.write(self._wake_w, b"\0")

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._once()
            except Exception:  # never let one bad iteration end the thread
                log.exception("%s: hub iteration failed", self.name)
                self._stop.wait(0.01)

    def _once(self) -> None:
        now = self.clock.now_ns()
        servers = self._servers
        deadline = min((s.next_wake_ns for s in servers), default=now + 1_000_000_000)
        events = self._sel.select(max(0.0, (deadline - now) / 1e9))
        if self._stop.is_set():
            return
        now = self.clock.now_ns()
        todo: dict[HubMember, None] = {}
        for key, _mask in events:
            if key.data is None:
                with contextlib.suppress(OSError):
                    while os.read(self._wake_r, 4096):
                        pass
                continue
            server, link = key.data
            server.receive(link, now)
            todo[server] = None
        while self._ops:
            op, server, done = self._ops.popleft()
            self._apply(op, server)
            done.set()
        for s in self._servers:
            if s.next_wake_ns <= now:
                todo[s] = None
        for s in todo:
            if s in self._servers:
                s.service(now)
