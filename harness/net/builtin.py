"""The built-in radio model: log-distance path loss, shadowing, SNR → PER, queues, airtime, collisions.

For every packet a sender enqueues (broadcasts expanded per receiver):

1. **Queue and airtime.** Each node sends one packet at a time: a packet starts when the node's medium
   is free (FIFO) and occupies it for ``preamble + 8·(header + payload) / bit_rate``. More than
   ``queue_limit`` packets waiting → drop (QUEUE).
2. **Path loss.** ``PL(d) = PL(d0) + 10·n·log10(d / d0)`` with ``PL(d0)`` the free-space loss at
   ``d0 = 1 m`` for the carrier frequency, plus seeded log-normal shadowing ``X ~ N(0, σ)`` drawn per
   packet and receiver. Received power ``P = P_tx − PL − X``; beyond ``max_range_m`` → drop (RANGE).
3. **Errors.** ``SNR = P − noise_floor``; bit error rate of BPSK on AWGN, ``BER = ½·erfc(√snr)``;
   ``PER = 1 − (1 − BER)^bits`` → drop (ERROR) with that probability.
4. **Medium access and collisions.** Like 802.11's CSMA/CA, a sender defers while a node it hears above
   ``carrier_sense_dbm`` is on the air, then waits a seeded random backoff (0–15 slots of 9 µs; a sender
   that finds the medium idle transmits at once); nodes
   that cannot hear each other (hidden terminals) still overlap. Another transmission overlapping in time
   at the receiver, received less than ``capture_db`` weaker, destroys a packet (COLLISION); so does the
   receiver transmitting meanwhile (half duplex).
5. **Delivery** at ``end of transmission + d / c``; a packet still in flight at the end of the interval is
   delivered in a later one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from harness.core.errors import ScenarioError
from harness.core.geo import Vec3
from harness.net.model import Delivery, Drop, DropCause, StepResult
from harness.wire.protocol import BROADCAST, Packet

C_M_S = 299_792_458.0


@dataclass(frozen=True)
class RadioConfig:
    tx_power_dbm: float = 20.0
    frequency_hz: float = 2.4e9
    path_loss_exponent: float = 2.7
    shadowing_sigma_db: float = 4.0
    noise_floor_dbm: float = -95.0
    bit_rate_bps: float = 6e6
    header_bytes: int = 48
    """MAC + IP + UDP headers added to every payload on the air."""
    preamble_s: float = 20e-6
    queue_limit: int = 64
    max_range_m: float = 2000.0
    capture_db: float = 10.0
    carrier_sense_dbm: float = -82.0
    """802.11 clear-channel threshold: a transmission heard above it makes a sender defer."""
    slot_s: float = 9e-6

    def __post_init__(self) -> None:
        for name in ("frequency_hz", "bit_rate_bps", "max_range_m"):
            if not getattr(self, name) > 0:
                raise ScenarioError(f"network.params.{name} must be > 0, got {getattr(self, name)}")
        if self.queue_limit < 1 or self.shadowing_sigma_db < 0 or self.path_loss_exponent <= 0:
            raise ScenarioError(
                "network.params: queue_limit >= 1, shadowing_sigma_db >= 0 and path_loss_exponent > 0 are required"
            )

    @property
    def reference_loss_db(self) -> float:
        """Free-space loss at 1 m: 20·log10(4π·d0/λ)."""
        return 20.0 * math.log10(4.0 * math.pi * self.frequency_hz / C_M_S)

    def mean_rx_dbm(self, distance_m: float) -> float:
        d = max(distance_m, 1.0)
        return self.tx_power_dbm - self.reference_loss_db - 10.0 * self.path_loss_exponent * math.log10(d)

    def airtime_s(self, payload_bytes: int) -> float:
        return self.preamble_s + 8.0 * (self.header_bytes + payload_bytes) / self.bit_rate_bps

    def per(self, snr_db: float, payload_bytes: int) -> float:
        snr = 10.0 ** (snr_db / 10.0)
        ber = 0.5 * math.erfc(math.sqrt(max(snr, 0.0)))
        bits = 8 * (self.header_bytes + payload_bytes)
        return 1.0 - (1.0 - ber) ** bits

    @classmethod
    def from_params(cls, params: Mapping[str, object]) -> RadioConfig:
        known = set(cls.__dataclass_fields__)
        for key in params:
            if key not in known:
                raise ScenarioError(f"network.params.{key}: unknown parameter (valid: {', '.join(sorted(known))})")
        values: dict[str, float | int] = {}
        for key, value in params.items():
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ScenarioError(f"network.params.{key}: expected a finite number, got {value!r}")
            values[key] = int(value) if key in ("header_bytes", "queue_limit") else float(value)
        return cls(**values)  # type: ignore[arg-type]


@dataclass
class _Tx:
    src: int
    start_ns: int
    end_ns: int
    packet: Packet
    positions: dict[int, Vec3]


@dataclass
class _Node:
    busy_until_ns: int = 0
    queued: list[int] = field(default_factory=list)
    """Start times of the packets accepted and not yet on the air."""


class BuiltinRadio:
    """Deterministic for a seed: the same packets and positions give the same drops and deliveries."""

    def __init__(self, cfg: RadioConfig | None = None, seed: int = 0) -> None:
        self.cfg = cfg or RadioConfig()
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 0x6E6574]))
        self.nodes: dict[int, _Node] = {}
        self.in_flight: list[tuple[int, Delivery]] = []
        self.recent: list[_Tx] = []
        self.delivered = 0
        self.dropped: dict[DropCause, int] = {c: 0 for c in DropCause}

    def step(self, t_ns: int, period_ns: int, positions: Mapping[int, Vec3], packets: Sequence[Packet]) -> StepResult:
        cfg = self.cfg
        drops: list[Drop] = []
        new: list[_Tx] = []
        pos = dict(positions)
        self.recent = [tx for tx in self.recent if tx.end_ns > t_ns]  # older ones overlap nothing new
        for pk in sorted(packets, key=lambda p: (p.t_ns, p.src, p.seq)):
            node = self.nodes.setdefault(pk.src, _Node())
            now = max(t_ns, pk.t_ns)
            start = max(now, node.busy_until_ns)
            node.queued = [st for st in node.queued if st > now]  # accepted, not yet on the air
            if len(node.queued) >= cfg.queue_limit:
                drops.append(self._drop(t_ns, pk, pk.dst, DropCause.QUEUE))
                continue
            airtime = round(cfg.airtime_s(len(pk.payload)) * 1e9)
            start = self._defer(pk.src, start, airtime, pos, self.recent + new)
            end = start + airtime
            node.busy_until_ns = end
            node.queued.append(start)
            new.append(_Tx(pk.src, start, end, pk, pos))
        self.recent += new
        for tx in new:
            src_pos = tx.positions.get(tx.src)
            overlapping = [o for o in self.recent if o is not tx and o.end_ns > tx.start_ns and o.start_ns < tx.end_ns]
            receivers = (
                [v for v in sorted(tx.positions) if v != tx.src] if tx.packet.dst == BROADCAST else [tx.packet.dst]
            )
            for dst in receivers:
                shadow = float(self.rng.normal(0.0, cfg.shadowing_sigma_db)) if cfg.shadowing_sigma_db else 0.0
                draw = float(self.rng.random())
                dst_pos = tx.positions.get(dst)
                if src_pos is None or dst_pos is None:
                    drops.append(self._drop(t_ns, tx.packet, dst, DropCause.RANGE))
                    continue
                d = math.dist(src_pos, dst_pos)
                if d > cfg.max_range_m:
                    drops.append(self._drop(t_ns, tx.packet, dst, DropCause.RANGE))
                    continue
                rx = cfg.mean_rx_dbm(d) - shadow
                if self._collides(tx, overlapping, dst, rx):
                    drops.append(self._drop(t_ns, tx.packet, dst, DropCause.COLLISION))
                    continue
                if draw < cfg.per(rx - cfg.noise_floor_dbm, len(tx.packet.payload)):
                    drops.append(self._drop(t_ns, tx.packet, dst, DropCause.ERROR))
                    continue
                at = tx.end_ns + round(d / C_M_S * 1e9)
                p = tx.packet
                delivered = Packet(p.t_ns, p.src, dst, p.port, p.seq, p.payload)
                self.in_flight.append((at, Delivery(at, delivered, rx)))
        end_ns = t_ns + period_ns
        due = sorted((d for at, d in self.in_flight if at < end_ns), key=lambda d: (d.at_ns, d.packet.dst))
        self.in_flight = [(at, d) for at, d in self.in_flight if at >= end_ns]
        self.delivered += len(due)
        return StepResult(due, drops)

    def next_event_ns(self) -> int | None:
        """When the next packet in flight arrives (None: nothing in flight, only new packets matter)."""
        return min((at for at, _ in self.in_flight), default=None)

    def _defer(self, src: int, start: int, airtime: int, pos: Mapping[int, Vec3], txs: list[_Tx]) -> int:
        """CSMA: move ``start`` past every transmission ``src`` can hear, plus a random backoff."""
        here = pos.get(src)
        if here is None:
            return start
        slot = round(self.cfg.slot_s * 1e9)
        moved = True
        while moved:
            moved = False
            for tx in txs:
                there = tx.positions.get(tx.src)
                if tx.src == src or there is None or tx.end_ns <= start or tx.start_ns >= start + airtime:
                    continue
                if self.cfg.mean_rx_dbm(math.dist(here, there)) >= self.cfg.carrier_sense_dbm:
                    start = tx.end_ns + int(self.rng.integers(0, 16)) * slot
                    moved = True
        return start

    def _collides(self, tx: _Tx, overlapping: list[_Tx], dst: int, rx_dbm: float) -> bool:
        dst_pos = tx.positions[dst]
        for other in overlapping:
            if other.src == dst:
                return True  # the receiver was transmitting (half duplex)
            o_pos = other.positions.get(other.src)
            if other.src == tx.src or o_pos is None:
                continue
            interferer = self.cfg.mean_rx_dbm(math.dist(o_pos, dst_pos))
            if interferer > rx_dbm - self.cfg.capture_db:
                return True
        return False

    def _drop(self, t_ns: int, pk: Packet, dst: int, cause: DropCause) -> Drop:
        self.dropped[cause] += 1
        return Drop(t_ns, pk, dst, cause)
