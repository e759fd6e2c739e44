"""The root's own bookkeeping per tick, in CPU time (robust to a loaded machine): what ``harness run`` does
at every tick besides physics, autopilots and the channel — the ledger row, the autopilot host's reports
(``unpack_ticks``, every 5th tick with the 5 ticks since its last), the summaries, and the recording at 50 Hz
(``world.mcap``, and with ``--view`` ``world.rrd`` too) — for N vehicles, half simulated in this process and
half in an autopilot host, as ``--workers auto`` splits them on two cores.

    .venv/bin/python benchmarks/bench_root.py                    # 10 and 100 vehicles
    .venv/bin/python benchmarks/bench_root.py 100 --view         # with world.rrd (Rerun installed)

It drives ``Launcher.record_rows``, ``Ledger``, ``protocol.unpack_ticks`` and the ``WorldTee`` directly with
synthetic truth; figures are µs of this process's CPU per tick (250 Hz).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from harness.record.sink import WorldTee
from harness.record.world import WorldRecorder
from harness.run.launcher import Launcher
from harness.run.ledger import Ledger, Row
from harness.run.result import VehicleSummary
from harness.wire import protocol as p

PHASE_EVERY = 5
RECORD_EVERY = 5  # 250 Hz ticks, 50 Hz recording


def root_us_per_tick(n: int, ticks: int, view: bool) -> float:
    own, hosted = range(n // 2), range(n // 2, n)
    truth = p.TruthReport((1.0, 2.0, -3.0), (0.1, 0.2, 0.3), (0.9, 0.1, 0.2, 0.3), 47.0, 8.0, 489.0, False, False)
    reports = p.pack_tick(truth, (0.5, 0.5, 0.5, 0.5), 3) * PHASE_EVERY
    with tempfile.TemporaryDirectory() as tmp:
        rrd: Any = None
        if view:
            from harness.record.rrd import RrdRecorder

            rrd = RrdRecorder(Path(tmp) / "world.rrd", n, (47.0, 8.0, 488.0), batch_s=2.0, min_wall_s=0.5)
        world = WorldTee(WorldRecorder(Path(tmp) / "world.mcap", 0, n), rrd)
        summaries = [VehicleSummary(i, "mission.py") for i in range(n)]
        ledger = Ledger(n)
        own_etas = [p.EndTickAC(0, v, (0.5,) * 4, 3) for v in own]
        host_etas = [p.EndTickAC(0, v, (0.5,) * 4, 0, reports) for v in hosted]
        start = time.process_time()
        for tick in range(ticks):
            row_truth: list[Any] = [None] * n
            for v in own:
                row_truth[v] = truth
            row = Row(tick, tick * 4_000_000, tick * 0.001, 10.0, row_truth, [()] * n, [0] * n)
            ledger.open(row)
            phase = tick % PHASE_EVERY == PHASE_EVERY - 1
            for e in own_etas + host_etas if phase else own_etas:
                if e.ticks:
                    ledger.reported(e.vehicle, tick, p.unpack_ticks(e.ticks))
                else:
                    row.motors[e.vehicle], row.status[e.vehicle] = e.motors, e.status
            done = list(ledger.complete())
            if done:
                Launcher.record_rows(done, RECORD_EVERY, summaries, world)
        cpu_s = time.process_time() - start
        world.close()
    return cpu_s / ticks * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="*", type=int, default=[10, 100])
    ap.add_argument("--ticks", type=int, default=5000, help="ticks per size (250 Hz: 5000 = 20 s of sim)")
    ap.add_argument("--view", action="store_true", help="world.rrd too (needs Rerun)")
    a = ap.parse_args()
    if any(n < 2 for n in a.sizes):
        ap.error("sizes: at least 2 vehicles (half here, half in an autopilot host)")
    print(
        f"root bookkeeping per tick, CPU µs (ledger, host reports, summaries, world.mcap{' + world.rrd' if a.view else ''})"
    )
    for n in a.sizes:
        us = root_us_per_tick(n, a.ticks, a.view)
        print(f"{n:>5} vehicles: {us:8.1f} µs/tick  ({us / n:.2f} µs per vehicle-tick)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
