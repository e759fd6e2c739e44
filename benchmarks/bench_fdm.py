"""Benchmark of the FDM: vehicle sub-steps per wall second, sensors and frames included.

    .venv/bin/python benchmarks/bench_fdm.py

Each case hovers N vehicles at the shipped default rates (1 kHz sub-step, 250 Hz tick) with sensor noise
on, on one core. Target (issue 3): >= 50,000 vehicle sub-steps per second, so that physics for 10
vehicles at 1 kHz costs under 20 % of real time.
"""

from __future__ import annotations

import sys
import time

from harness.fdm.physics import Physics, PhysicsConfig

TARGET = 50_000


def run(n: int, ticks: int) -> float:
    ph = Physics(PhysicsConfig(n_vehicles=n, seed=1))
    u = ph.cfg.quad.hover_command
    cmds = [(u, u, u, u)] * n
    for _ in range(50):
        ph.step(cmds)
    t = time.perf_counter()
    for _ in range(ticks):
        ph.step(cmds)
    elapsed = time.perf_counter() - t
    return n * ticks * ph.substeps / elapsed


def main() -> int:
    print("FDM: JSBSim quad-X + sensors, 1 kHz sub-step, 250 Hz tick, noise on, one core")
    print(f"{'vehicles':>8} {'substeps/s':>12} {'ratio to target':>16} {'cost of 1 kHz real time':>24}")
    for n, ticks in ((1, 5000), (10, 1000), (100, 100)):
        rate = run(n, ticks)
        load = n * 1000 / rate
        print(f"{n:>8} {rate:>12,.0f} {rate / TARGET:>15.2f}x {100 * load:>22.1f} %", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
