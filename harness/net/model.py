"""The network model seam: what a type-1 network simulator does with one phase-1 interval."""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

from harness.simclock.protocol import Packet

Vec3 = tuple[float, float, float]


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
