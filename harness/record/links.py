"""Radio link quality from the network events: the recent delivery ratio of every pair of vehicles.

A pure core for the 3D view (``harness.record.rrd``): it is fed the events of ``network-events.jsonl``
(``{"t_s", "kind": "deliver"|"drop", "src", "dst", ...}``) in any order within a few phases, and answers,
for a sim time, each undirected pair's delivery ratio over the last ``window_s`` seconds, and the drops
since it was last asked.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

Pair = tuple[int, int]


def pair_of(a: int, b: int) -> Pair:
    return (a, b) if a <= b else (b, a)


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
class LinkTracker:
    """Sliding-window delivery ratio per pair. Broadcast packets count once per receiver, as the events do."""

    window_s: float = 2.0
    _events: dict[Pair, deque[tuple[float, bool]]] = field(default_factory=dict)
    _new_drops: list[Drop] = field(default_factory=list)

    def add(self, event: dict[str, object]) -> None:
        """One line of ``network-events.jsonl``; anything that is not a delivery or drop between two vehicles
        is ignored (a broadcast drop with no receiver has ``dst`` -1)."""
        kind = event.get("kind")
        src, dst, t = event.get("src"), event.get("dst"), event.get("t_s")
        if kind not in ("deliver", "drop") or not isinstance(src, int) or not isinstance(dst, int):
            return
        if not isinstance(t, int | float) or src < 0 or dst < 0 or src == dst:
            return
        ok = kind == "deliver"
        self._events.setdefault(pair_of(src, dst), deque()).append((float(t), ok))
        if not ok:
            self._new_drops.append(Drop(float(t), src, dst, str(event.get("cause", ""))))

    def quality(self, now_s: float) -> list[LinkQuality]:
        """Every pair with an attempt in ``(now_s - window_s, now_s]``, sorted by pair."""
        out = []
        start = now_s - self.window_s
        for pair in sorted(self._events):
            q = self._events[pair]
            while q and q[0][0] <= start:
                q.popleft()
            delivered = sum(1 for t, ok in q if ok and t <= now_s)
            dropped = sum(1 for t, ok in q if not ok and t <= now_s)
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
