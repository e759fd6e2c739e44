"""Network step cost: N vehicles each broadcasting a 100-byte packet at 10 Hz, built-in model.

    .venv/bin/python benchmarks/bench_net.py

Phases at 50 Hz (every 5th tick of 250 Hz); vehicles on a grid 20 m apart (all in range of each other for
the built-in model: the worst case for broadcast expansion and collision checks). Prints the cost of one
phase-1 step and of one second of sim time, for the built-in model and for ns-3 (when installed).
"""

from __future__ import annotations

import math
import subprocess
import sys
import time

from harness.net.builtin import BuiltinRadio
from harness.net.model import NetworkModel
from harness.wire.protocol import BROADCAST, Packet

PERIOD_NS = 20_000_000


def run(n: int, seconds: float = 10.0, model: str = "builtin") -> tuple[float, float]:
    radio: NetworkModel
    if model == "builtin":
        radio = BuiltinRadio(seed=1)
    else:
        from harness.net.ns3model import Ns3Config, Ns3Radio

        radio = Ns3Radio(Ns3Config(max_vehicles=n), seed=1)
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
    print("N vehicles broadcasting 100 B at 10 Hz, phase 1 at 50 Hz")
    print(f"{'model':>8} {'vehicles':>8} {'us per step':>12} {'s per sim s':>12}")
    models = ["builtin"]
    try:
        import ns  # noqa: F401

        models.append("ns3")
    except ImportError:
        print("(ns-3 not installed: pip install 'uav-harness[ns3]')")
    for model in models:
        for n in (10, 50, 100):
            seconds = 10.0 if n < 100 else 4.0
            if model == "ns3":  # ns-3's simulator is a process-wide singleton: one process per size
                out = subprocess.run(
                    [sys.executable, __file__, "--one", model, str(n), str(seconds)], capture_output=True, text=True
                ).stdout.split()
                per_step, per_s = float(out[-2]), float(out[-1])
            else:
                per_step, per_s = run(n, seconds, model)
            print(f"{model:>8} {n:>8} {per_step:>12.0f} {per_s:>12.3f}", flush=True)
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--one":
        step_us, sim_s = run(int(sys.argv[3]), float(sys.argv[4]), sys.argv[2])
        print(step_us, sim_s)
        sys.exit(0)
    sys.exit(main())
