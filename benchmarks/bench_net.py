"""Network step cost: N vehicles each broadcasting a 100-byte packet at 10 Hz, built-in model.

    .venv/bin/python benchmarks/bench_net.py

Phases at 50 Hz (every 5th tick of 250 Hz); vehicles on a grid 20 m apart (all in range: the worst case
for broadcast expansion and collision checks). Prints the cost of one phase-1 step and of one second of
sim time. ns-3 is not measured: the ns-3 model is not in this build yet.
"""

from __future__ import annotations

import math
import sys
import time

from harness.net.builtin import BuiltinRadio
from harness.simclock.protocol import BROADCAST, Packet

PERIOD_NS = 20_000_000


def run(n: int, seconds: float = 10.0) -> tuple[float, float]:
    radio = BuiltinRadio(seed=1)
    cols = math.ceil(math.sqrt(n))
    pos = {i: (20.0 * (i // cols), 20.0 * (i % cols), -10.0) for i in range(n)}
    steps = round(seconds * 1e9 / PERIOD_NS)
    seq = 0
    start = time.perf_counter()
    for k in range(steps):
        t = k * PERIOD_NS
        # 10 Hz each: every vehicle sends in one of the 5 phases of each 100 ms
        packets = [Packet(t, v, BROADCAST, 0, seq + v, b"p" * 100) for v in range(n) if (v + k) % 5 == 0]
        seq += n
        radio.step(t, PERIOD_NS, pos, packets)
    elapsed = time.perf_counter() - start
    return elapsed / steps * 1e6, elapsed / seconds


def main() -> int:
    print("built-in radio: N vehicles broadcasting 100 B at 10 Hz, phase 1 at 50 Hz")
    print(f"{'vehicles':>8} {'us per step':>12} {'s per sim s':>12}")
    for n in (10, 50, 100):
        per_step, per_s = run(n, 10.0 if n < 100 else 4.0)
        print(f"{n:>8} {per_step:>12.0f} {per_s:>12.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
