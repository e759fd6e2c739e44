"""``world.mcap``'s writer alone, in CPU time: µs per vehicle sample (three messages: pose, fix, state) for a
swarm's recording, the file closed (its summary: chunk and message indexes) included.

    .venv/bin/python benchmarks/bench_world.py [--vehicles 100] [--ticks 500] [--repeat 5]

The samples are built before the clock starts; the figure is the best of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from harness.record.sample import VehicleSample
from harness.record.world import WorldRecorder


def us_per_sample(vehicles: int, ticks: int) -> float:
    rows = [
        [
            VehicleSample(
                k * 20_000_000, v, (1.0 + k / 3, -2.0 * v, -k / 7), (0.9, 0.1, -0.2, 0.3), (0.1 * k, 0.2, -0.3),
                47.0 + k * 1e-7, 8.0 - v * 1e-6, 488.5 + k / 9, (0.5, 0.5, 0.25, 0.3), False, False, 3,
            )
            for v in range(vehicles)
        ]
        for k in range(ticks)
    ]  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        rec = WorldRecorder(Path(tmp) / "world.mcap", 0, vehicles)
        start = time.process_time()
        for row in rows:
            for s in row:
                rec.vehicle(s)
        rec.close()
        return (time.process_time() - start) / (vehicles * ticks) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=100)
    ap.add_argument("--ticks", type=int, default=500, help="recorded ticks (50 Hz: 500 = 10 s of sim)")
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    runs = [us_per_sample(a.vehicles, a.ticks) for _ in range(a.repeat)]
    print(
        f"world.mcap, {a.vehicles} vehicles x {a.ticks} recorded ticks: {min(runs):.2f} µs CPU per vehicle sample "
        f"(best of {a.repeat}: {', '.join(f'{r:.2f}' for r in runs)})"
    )


if __name__ == "__main__":
    main()
