"""The quiet tick in isolation: ``Channel.step`` with in-process autopilots only and no phase (4 ticks of 5 in
``harness run``), in microseconds per tick. ``bench_channel.py`` never runs such a tick (phases on every tick,
its autopilots in a process of their own), so a change to the quiet tick is measured here.

    .venv/bin/python benchmarks/bench_quiet_tick.py             # the tick as the channel runs it
    .venv/bin/python benchmarks/bench_quiet_tick.py --general   # the same tick forced through the general path

The in-process autopilots answer at once (no flight stack): what is left is the channel's own work. Each figure
is the median of ``--repeat`` runs of ``--ticks`` ticks (phase ticks not counted).
"""

from __future__ import annotations

import argparse
import statistics
import time

from harness.channel import Channel, ChannelConfig
from harness.wire import protocol as p

TICK_NS = 4_000_000


def quiet_tick_us(vehicles: int, ticks: int, general: bool) -> float:
    ch = Channel(ChannelConfig(address="tcp://127.0.0.1:0", phase_every=5, stall_timeout_s=30))
    ch.attach_physics()
    ch.attach_local_autopilots(range(vehicles), lambda m: p.EndTickAC(m.t_ns, m.vehicle, (0.5, 0.5, 0.5, 0.5)))
    if general:
        ch.machine.local_only = lambda begin_ticks: None  # type: ignore[method-assign]
    total_ns = quiet = 0
    try:
        for k in range(ticks):
            begin = [p.BeginTickAC(k * TICK_NS, k, v, vehicles, (0.0, 0.0, 0.0), b"") for v in range(vehicles)]
            start = time.perf_counter_ns()
            etas = ch.step(begin)
            if k % 5:
                total_ns += time.perf_counter_ns() - start
                quiet += 1
            assert len(etas) == vehicles
    finally:
        ch.close()
    return total_ns / quiet / 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--general", action="store_true", help="force every tick through the general path")
    ap.add_argument("--ticks", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--vehicles", type=int, nargs="+", default=[1, 10])
    a = ap.parse_args()
    for n in a.vehicles:
        us = statistics.median(quiet_tick_us(n, a.ticks, a.general) for _ in range(a.repeat))
        print(f"{'general' if a.general else 'as run'} path, {n:3d} vehicles: {us:6.2f} us per quiet tick")


if __name__ == "__main__":
    main()
