"""Radio link quality from the network events: the recent delivery ratio of every pair of vehicles.

A pure core for the 3D view (``harness.record.rrd``): it is fed the events of ``network-events.jsonl``
(``{"t_s", "kind": "deliver"|"drop", "src", "dst", ...}``) in any order within a few phases, and answers,
for a sim time, each undirected pair's delivery ratio over the last ``window_s`` seconds, and the drops
since it was last asked.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import msgspec

Pair = tuple[int, int]


def pair_of(a: int, b: int) -> Pair:
    return (a, b) if a <= b else (b, a)


class NetEvent(msgspec.Struct):
    """The fields of a ``network-events.jsonl`` line that the view uses."""

    t_s: float
    kind: str
    src: int
    dst: int
    cause: str = ""


_decode_many = msgspec.json.Decoder(list[NetEvent]).decode
_decode_one = msgspec.json.Decoder(NetEvent).decode


@dataclass(frozen=True)
class Drop:
    t_s: float
    src: int
    dst: int
    cause: str


@dataclass(frozen=True)
class LinkQuality:
    pair: Pair
    delivered: int
    dropped: int

    @property
    def ratio(self) -> float:
        """Delivered / attempted in the window (1.0 when nothing was attempted)."""
        total = self.delivered + self.dropped
        return self.delivered / total if total else 1.0


@dataclass
class _PairCounts:
    """Deliveries and drops of one pair in time buckets (oldest first), with running totals."""

    buckets: deque[list[int]] = field(default_factory=deque)
    """[bucket index, delivered, dropped]"""
    delivered: int = 0
    dropped: int = 0


@dataclass
class LinkTracker:
    """Sliding-window delivery ratio per pair. Broadcast packets count once per receiver, as the events do.

    Events are counted in ``bucket_s`` buckets with running totals, so asking costs per pair, not per event
    (at 50 vehicles beaconing at 10 Hz that is 24,500 events per sim second).
    """

    window_s: float = 2.0
    bucket_s: float = 0.1
    _pairs: dict[Pair, _PairCounts] = field(default_factory=dict)
    _new_drops: list[Drop] = field(default_factory=list)

    def add(self, event: dict[str, object]) -> None:
        """One event as a dict (a decoded line of ``network-events.jsonl``)."""
        kind = event.get("kind")
        src, dst, t = event.get("src"), event.get("dst"), event.get("t_s")
        if isinstance(kind, str) and isinstance(src, int) and isinstance(dst, int) and isinstance(t, int | float):
            self._add(float(t), kind, src, dst, str(event.get("cause", "")))

    def add_lines(self, lines: list[bytes]) -> None:
        """Complete lines of ``network-events.jsonl``, decoded in one go (a malformed line is skipped)."""
        if not lines:
            return
        try:
            events = _decode_many(b"[" + b",".join(lines) + b"]")
        except msgspec.DecodeError:
            events = []
            for line in lines:
                try:
                    events.append(_decode_one(line))
                except msgspec.DecodeError:
                    continue
        for e in events:
            self._add(e.t_s, e.kind, e.src, e.dst, e.cause)

    def _add(self, t_s: float, kind: str, src: int, dst: int, cause: str) -> None:
        """Anything but a delivery or drop between two vehicles is ignored (a broadcast drop with no receiver
        has ``dst`` -1)."""
        if kind not in ("deliver", "drop") or src < 0 or dst < 0 or src == dst:
            return
        ok = kind == "deliver"
        pc = self._pairs.get(pair_of(src, dst))
        if pc is None:
            pc = self._pairs[pair_of(src, dst)] = _PairCounts()
        idx = math.floor(t_s / self.bucket_s)
        if not pc.buckets or pc.buckets[-1][0] != idx:
            pc.buckets.append([idx, 0, 0])
        bucket = pc.buckets[-1]
        if ok:
            bucket[1] += 1
            pc.delivered += 1
        else:
            bucket[2] += 1
            pc.dropped += 1
            self._new_drops.append(Drop(t_s, src, dst, cause))

    def quality(self, now_s: float) -> list[LinkQuality]:
        """Every pair with an attempt in ``(now_s - window_s, now_s]``, sorted by pair."""
        out = []
        lo = math.floor((now_s - self.window_s) / self.bucket_s)
        hi = math.floor(now_s / self.bucket_s)
        for pair in sorted(self._pairs):
            pc = self._pairs[pair]
            while pc.buckets and pc.buckets[0][0] <= lo:  # left the window for good
                _, d, x = pc.buckets.popleft()
                pc.delivered -= d
                pc.dropped -= x
            delivered, dropped = pc.delivered, pc.dropped
            for idx, d, x in reversed(pc.buckets):  # read ahead of now_s: not counted yet
                if idx <= hi:
                    break
                delivered -= d
                dropped -= x
            if delivered or dropped:
                out.append(LinkQuality(pair, delivered, dropped))
        return out

    def pop_drops(self, until_s: float) -> list[Drop]:
        """The drops added since the last call, up to ``until_s`` (later ones wait for a later call)."""
        out = [d for d in self._new_drops if d.t_s <= until_s]
        self._new_drops = [d for d in self._new_drops if d.t_s > until_s]
        return out


def ratio_color(ratio: float) -> tuple[int, int, int]:
    """Red (0 % delivered) through yellow to green (100 %)."""
    r = max(0.0, min(1.0, ratio))
    if r < 0.5:
        return (230, int(460 * r), 40)
    return (int(230 * (1.0 - r) * 2), 210, 40)
