"""The network model seam: what a type-1 network simulator does with one phase-1 interval."""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

from harness.core.geo import Vec3
from harness.wire.protocol import EVERY_PHASE, NO_DEADLINE, Packet


class NetworkKind(enum.StrEnum):
    """The network simulator of a run (its value is the scenario file's ``network.model`` and ``--network``)."""

    NONE = "none"
    BUILTIN = "builtin"
    NS3 = "ns3"


class DropCause(enum.Enum):
    RANGE = "range"
    """Beyond the model's range, or the receiver has no position (not in the world)."""
    ERROR = "error"
    """Bit errors: the received SNR was too low for this packet size."""
    COLLISION = "collision"
    """Another transmission overlapped it at the receiver too strongly to capture."""
    QUEUE = "queue"
    """The sender's transmit queue was full."""


@dataclass(frozen=True)
class Delivery:
    at_ns: int
    """Sim time the last bit arrived at the receiver."""
    packet: Packet
    """With ``dst`` set to the receiver (broadcasts are expanded per receiver)."""
    rssi_dbm: float


@dataclass(frozen=True)
class Drop:
    t_ns: int
    packet: Packet
    dst: int
    cause: DropCause


@dataclass
class StepResult:
    deliveries: list[Delivery]
    drops: list[Drop]


class NetworkModel(Protocol):
    def step(self, t_ns: int, period_ns: int, positions: Mapping[int, Vec3], packets: Sequence[Packet]) -> StepResult:
        """Simulate [t, t + period): take the packets enqueued in this tick's phase 0, return what arrives
        in the interval (earlier packets may arrive now: models keep transmissions in flight)."""
        ...


def lookahead_ns(model: NetworkModel, t_ns: int, period_ns: int) -> int:
    """END-TICK-1's ``idle_until_ns`` for ``model`` after the interval starting at ``t_ns``.

    A model with ``next_event_ns()`` (the built-in radio) is left out of phase 1 until the interval that
    holds its next arrival, unless new packets come; any other model (ns-3, whose own events run between
    packets) takes part in every phase 1.
    """
    next_event = getattr(model, "next_event_ns", None)
    if next_event is None:
        return EVERY_PHASE
    at = next_event()
    if at is None:
        return NO_DEADLINE
    return max(t_ns + 1, at - period_ns + 1)  # the first phase tick t with t + period > at
