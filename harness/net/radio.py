"""The messaging API for missions (the paper's Python messaging module): radio over the simulated network.

    from harness.net import radio
    radio.broadcast(b"hello")                  # to every vehicle in range
    radio.send(2, b"to vehicle 2")
    msg = radio.receive(timeout=1.0)           # blocks up to 1 s of *sim* time; None on timeout
    msg = await radio.receive_async(timeout=1.0)

Packets handed over in phase 0 of tick k go to the network simulator in phase 1 of tick k; the script sees
them at the first phase 0 after they arrive. Only inside ``harness mission`` / ``harness run``.
"""

from __future__ import annotations

import asyncio
import os
from dataclasses import dataclass

from harness.core.errors import HarnessError
from harness.simclock.installed import current
from harness.simclock.mailbox import Delivery
from harness.simclock.runtime import SimRuntime
from harness.simclock.threads import Kind
from harness.wire.protocol import BROADCAST


@dataclass(frozen=True)
class Message:
    src: int
    """Sending vehicle."""
    payload: bytes
    port: int
    received_at_s: float
    """Sim time the packet arrived."""
    rssi_dbm: float


def _rt() -> SimRuntime:
    rt = current()
    if rt is None:
        raise HarnessError("harness.net.radio works only in a mission run by `harness mission` / `harness run`")
    return rt


def vehicle() -> int:
    """This mission's vehicle index."""
    return int(os.environ.get("HARNESS_VEHICLE", "0"))


def send(to_vehicle: int, payload: bytes, port: int = 0) -> None:
    if to_vehicle < 0:
        raise ValueError(f"vehicle must be >= 0 (use broadcast() for everyone), got {to_vehicle}")
    _rt().queue_packet(to_vehicle, port, bytes(payload))


def broadcast(payload: bytes, port: int = 0) -> None:
    _rt().queue_packet(BROADCAST, port, bytes(payload))


def _message(d: Delivery | None) -> Message | None:
    return None if d is None else Message(d.src, d.payload, d.port, d.at_ns / 1e9, d.rssi_dbm)


def receive(timeout: float | None = None) -> Message | None:
    """The next message; blocks up to ``timeout`` seconds of sim time (None: until one arrives)."""
    return _message(_take(_rt(), timeout))


def _take(rt: SimRuntime, timeout_s: float | None) -> Delivery | None:
    """The oldest delivered packet, waiting up to ``timeout_s`` of sim time for one (None: until one comes), counted
    idle (an ``INBOX`` blocker); None on timeout or when the run is over."""
    deadline = None if timeout_s is None else rt.now_ns() + round(timeout_s * 1e9)
    while True:
        found = rt.mail.pop()  # deliveries only arrive between phases, never while this runs
        if found is not None:
            return found
        if rt.closed or (deadline is not None and rt.now_ns() >= deadline):
            return None
        w = rt.new_waiter(Kind.INBOX, deadline_ns=deadline, inbox=True)
        w.lock.acquire()
        rt.finish_wait(w)


def _resolve(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)


async def receive_async(timeout: float | None = None) -> Message | None:
    """Like :func:`receive`, without blocking the event loop: it awaits the next delivery (or ``timeout``
    seconds of sim time) as a future, so an idle script is not woken at every phase."""
    rt = _rt()
    deadline = None if timeout is None else rt.now_ns() + round(timeout * 1e9)
    loop = asyncio.get_running_loop()
    while True:
        msg = _message(_take(rt, 0.0))
        if msg is not None or rt.closed:
            return msg
        left_ns = None if deadline is None else deadline - rt.now_ns()
        if left_ns is not None and left_ns <= 0:
            return None
        arrived: asyncio.Future[None] = loop.create_future()

        def on_delivery(fut: asyncio.Future[None] = arrived) -> None:
            loop.call_soon_threadsafe(_resolve, fut)

        token = rt.add_inbox_callback(on_delivery)
        try:
            await asyncio.wait_for(arrived, None if left_ns is None else left_ns / 1e9)
        except TimeoutError:
            pass
        finally:
            rt.remove_inbox_callback(token)
