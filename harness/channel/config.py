"""What a channel is told (``ChannelConfig``) and what it reports (``Fault``, ``MissionExit``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from harness.core.clock import NS_PER_S
from harness.core.errors import ScenarioError
from harness.wire.transport import parse_address


@dataclass(frozen=True)
class ChannelConfig:
    address: str = "tcp://127.0.0.1:0"
    """Where to listen. Anything but loopback (or a unix socket) requires ``secret``."""
    name: str = "channel"
    parent: str | None = None
    """Address of the parent channel: this channel is then a child in a tree."""
    secret: bytes | None = None
    """Shared secret every peer must prove (HMAC of a nonce); required off loopback."""
    tick_hz: float = 250.0
    phase_every: int = 1
    """Phases 0 and 1 run on every tick whose index is a multiple of this (root only)."""
    stall_timeout_s: float = 10.0
    """Wall-clock limit on every wait for a subscriber's answer."""
    join_timeout_s: float = 30.0
    """Wall-clock limit on waiting for an autopilot of a vehicle that physics simulates."""
    handshake_timeout_s: float = 10.0
    type1_fault: Literal["fail", "drop"] = "fail"
    epoch_ns: int = 0
    """Unix time of sim time zero, told to every peer; 0 means the wall time at start."""
    trace: bool = False
    """Record (wall ns, event, tick, peer) for every phase transition (tests, debugging)."""
    overlap_phase1: bool = True
    """Root only. True: END-TICK-AC go back to physics as soon as phase 0 and the autopilots are done, and
    phase 1 (the network simulating the interval with the positions of its tick) runs while physics
    integrates the next ticks; the next phase 0 starts only when every END-TICK-1 is in. Nothing inside the
    simulation can tell the difference: missions are not running then, and the network saw only its
    tick's positions. False: the paper's strict order (physics waits for every END-TICK-1), which is also what
    happens while a child channel takes part in the phase."""

    def __post_init__(self) -> None:
        if self.tick_hz <= 0:
            raise ScenarioError(f"channel: tick_hz must be > 0, got {self.tick_hz}")
        if self.phase_every < 1:
            raise ScenarioError(f"channel: phase_every must be a positive integer, got {self.phase_every}")
        if self.stall_timeout_s <= 0:
            raise ScenarioError(f"channel: stall_timeout_s must be > 0, got {self.stall_timeout_s}")
        if not parse_address(self.address).is_loopback and not self.secret:
            raise ScenarioError(
                f"channel {self.name}: listening on {self.address} (not loopback) requires a shared secret"
            )

    @property
    def phase_period_ns(self) -> int:
        return round(self.phase_every * NS_PER_S / self.tick_hz)


@dataclass(frozen=True)
class Fault:
    """A peer that was dropped or failed the run."""

    peer: str
    kind: str
    vehicle: int
    reason: str
    tick: int
    fatal: bool


@dataclass
class MissionExit:
    peer: str
    vehicle: int
    exit_code: int
    reason: str
