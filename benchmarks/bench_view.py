"""The 3D view's own cost: CPU seconds (all threads of this process, Rerun's encoders included) that
recording ``world.rrd`` adds per second of sim time, fed exactly as the launcher feeds it (every vehicle at
50 Hz, tick timing at 50 Hz) and batched as in a run that is not faster than real time (the most batches per
sim second), next to what ``world.mcap`` costs. Independent of the machine's load, unlike
the full-stack figures; compare it with the CPU ``harness run`` spends per sim second
(``bench_fullstack.py``).

    .venv/bin/python benchmarks/bench_view.py            # 1, 10 and 50 vehicles, 60 s of sim each
    .venv/bin/python benchmarks/bench_view.py 10 --serve # with the live gRPC stream served (no viewer)
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

from harness.core.clock import NS_PER_S
from harness.core.freeport import free_tcp_port
from harness.record.rrd import RrdRecorder
from harness.record.sample import VehicleSample
from harness.record.world import WorldRecorder

RECORD_HZ = 50


def feed(sink: RrdRecorder | WorldRecorder, n: int, sim_s: float) -> float:
    """CPU seconds to record ``sim_s`` of ``n`` vehicles flying circles, closing the file included."""
    step_ns = NS_PER_S // RECORD_HZ
    cpu0 = time.process_time()
    for k in range(int(sim_s * RECORD_HZ)):
        t_ns = k * step_ns
        t = t_ns / NS_PER_S
        for i in range(n):
            a = 0.1 * t + i
            sink.vehicle(
                VehicleSample(
                    t_ns=t_ns,
                    vehicle=i,
                    pos_ned_m=(20 * math.cos(a), 20 * math.sin(a), -10.0),
                    quat_wxyz=(math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)),
                    vel_ned_m_s=(-2 * math.sin(a), 2 * math.cos(a), 0.0),
                    lat_deg=47.0 + 1e-5 * math.cos(a),
                    lon_deg=8.0 + 1e-5 * math.sin(a),
                    alt_amsl_m=500.0,
                    motors=(0.5, 0.5, 0.5, 0.5),
                    on_ground=False,
                    crashed=False,
                )
            )
        sink.tick(t_ns, k * 5, t / 20.0, 50.0)
    sink.close()
    return time.process_time() - cpu0


def links_cpu(n: int, sim_s: float, beacon_hz: float = 10.0) -> float:
    """CPU seconds per sim second to read the network events of ``n`` vehicles each broadcasting at
    ``beacon_hz`` to all others (what the view reads from ``network-events.jsonl``), as it does: a batch of
    lines every 0.5 s, the links' state twice a second."""
    import json

    from harness.record.links import LinkTracker

    tracker = LinkTracker()
    per_batch = int(n * (n - 1) * beacon_hz * 0.5)
    cpu = 0.0
    for b in range(int(sim_s * 2)):
        t0 = 0.5 * b
        lines = [
            json.dumps(
                {"t_s": t0 + 0.5 * k / per_batch, "kind": "deliver" if k % 9 else "drop", "src": k % n}
                | {"dst": (k // n) % n, "rssi_dbm": -71.5, "cause": "snr"}
            ).encode()
            for k in range(per_batch)
        ]
        c = time.process_time()
        tracker.add_lines(lines)
        tracker.quality(t0 + 0.5)
        tracker.pop_drops(t0 + 0.5)
        cpu += time.process_time() - c
    return cpu / sim_s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="*", type=int, default=[1, 10, 50])
    ap.add_argument("--sim", type=float, default=60.0, help="seconds of sim time per size")
    ap.add_argument("--serve", action="store_true", help="also serve the live stream (as --view does)")
    a = ap.parse_args()
    print(
        f"{'vehicles':>8} {'mcap CPU s/sim s':>17} {'rrd CPU s/sim s':>16} {'rrd MB/sim min':>15} "
        f"{'+ radio links CPU s/sim s (10 Hz beacons)':>42}"
    )
    for n in a.sizes:
        with tempfile.TemporaryDirectory() as d:
            out = Path(d)
            mcap = feed(WorldRecorder(out / "world.mcap", 0, n), n, a.sim)
            rrd_sink = RrdRecorder(  # batches as in a run, at the worst: as many as sim time allows (min_wall_s 0)
                out / "world.rrd",
                n,
                (47.0, 8.0, 500.0),
                serve_port=free_tcp_port() if a.serve else None,
                batch_s=0.5 * max(1.0, n / 25) if a.serve else 2.0,  # as harness.record.sink.open_world
                min_wall_s=0.0,
            )
            rrd = feed(rrd_sink, n, a.sim)
            size = (out / "world.rrd").stat().st_size / 1e6 * 60.0 / a.sim
            links = links_cpu(n, min(a.sim, 20.0))
            print(f"{n:>8} {mcap / a.sim:>17.4f} {rrd / a.sim:>16.4f} {size:>15.1f} {links:>42.4f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
