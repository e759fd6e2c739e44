"""A mission's packets on the simulated radio: what the network delivered to it, and what it sends.

Deliveries arrive from the channel between phases (the clock thread); the script takes them in phase 0
(``SimRuntime.take_delivery``, ``udp``'s radio sockets); what it sends goes out before the phase's END-TICK-0.
Read and written under the runtime's lock, or where only one side runs (deliveries never arrive during phase 0).
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class Delivery:
    at_ns: int
    src: int
    dst: int
    port: int
    payload: bytes
    rssi_dbm: float


@dataclass
class Outgoing:
    dst: int
    port: int
    payload: bytes


@dataclass
class Mailbox:
    inbox: collections.deque[Delivery] = field(default_factory=collections.deque)
    outbox: list[Outgoing] = field(default_factory=list)
    callbacks: dict[int, Callable[[], None]] = field(default_factory=dict)
    """Called (on the clock thread) when a packet is delivered: ``receive_async`` wakes its event loop so."""
    _next_token: int = 0

    def pop(self, port: int | None = None) -> Delivery | None:
        """The oldest delivered packet (for ``port``, or any), or None."""
        inbox = self.inbox
        if port is None:
            return inbox.popleft() if inbox else None
        for i, d in enumerate(inbox):
            if d.port == port:
                del inbox[i]
                return d
        return None

    def has(self, port: int) -> bool:
        return any(d.port == port for d in self.inbox)

    def add_callback(self, cb: Callable[[], None]) -> int:
        self._next_token += 1
        self.callbacks[self._next_token] = cb
        return self._next_token

    def take_outbox(self) -> list[Outgoing]:
        out, self.outbox = self.outbox, []
        return out
