"""The root's cost per vehicle as a run grows: CPU per tick and resident memory at 10 … 500 vehicles.

Each size is one ``harness run --vehicles N --cluster local:K --duration S`` (no missions: the root's own work
is what grows with N): the vehicles' physics and autopilots are on the local Dask cluster's workers, the
root keeps the channel, the ledger and the recordings of every vehicle. Figures come from the run's
``summary.json``: ``root`` (the tick loop's CPU on the root's main thread, the whole process's CPU, the resident
memory at the end) and ``cluster.workers`` (each share's CPU per vehicle-tick). CPU time, not wall time: robust
enough on a shared machine (say the load beside the figures).

    .venv/bin/python benchmarks/bench_scale.py                       # 10 100 300 500, local:2, 2 s of sim
    .venv/bin/python benchmarks/bench_scale.py 10 100 --duration 5 --cluster local:1
    .venv/bin/python benchmarks/bench_scale.py 100 --mission missions/hover.py -- 5   # with missions
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def run(n: int, cluster: str, duration: float | None, mission: str | None, args: list[str]) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as tmp:
        argv = [sys.executable, "-m", "harness.cli", "run", "--vehicles", str(n), "--cluster", cluster]
        argv += ["--no-progress", "--out", tmp]
        if duration is not None:
            argv += ["--duration", str(duration)]
        if mission:
            argv += ["--mission", mission, "--", *args]
        t0 = time.monotonic()
        proc = subprocess.run(argv, capture_output=True, text=True)
        wall = time.monotonic() - t0
        summary = json.loads((Path(tmp) / "summary.json").read_text()) if (Path(tmp) / "summary.json").is_file() else {}
    if proc.returncode != 0 or "root" not in summary:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise SystemExit(f"{n} vehicles: harness run exited {proc.returncode}: {' / '.join(tail)}")
    return {"n": n, "wall_s": wall, "load": os.getloadavg()[0], **summary}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="*", type=int, default=[10, 100, 300, 500])
    ap.add_argument("--cluster", default="local:2")
    ap.add_argument("--duration", type=float, default=2.0, help="sim seconds per run (none with --mission)")
    ap.add_argument("--mission", default=None, help="one mission per vehicle (the run ends with them)")
    ap.add_argument("--json", default=None, help="also write every run's figures to this file")
    a, rest = ap.parse_known_args()
    rest = rest[1:] if rest[:1] == ["--"] else rest
    rows = []
    print(
        "vehicles  sim_s  wall_s  RTF     root loop µs/tick  µs/vehicle-tick  process µs/vehicle-tick  "
        "root RSS MB  MB/vehicle*  worker µs/vehicle-tick  load",
        flush=True,
    )
    for n in a.sizes:
        r = run(n, a.cluster, None if a.mission else a.duration, a.mission, rest)
        rows.append(r)
        root = r["root"]
        workers = r["cluster"]["workers"]
        worker_us = sum(w["cpu_us_per_vehicle_tick"] * (w["vehicles"][1] - w["vehicles"][0] + 1) for w in workers) / n
        first = rows[0]
        per_mb = (root["rss_mb"] - first["root"]["rss_mb"]) / (n - first["n"]) if n != first["n"] else float("nan")
        print(
            f"{n:8d}  {r['sim_time_s']:5.1f}  {r['wall_s']:6.1f}  {r['real_time_factor']:5.3f}  "
            f"{root['loop_cpu_us_per_tick']:17.0f}  {root['loop_cpu_us_per_vehicle_tick']:15.2f}  "
            f"{root['process_cpu_us_per_vehicle_tick']:23.2f}  {root['rss_mb']:11.1f}  {per_mb:11.3f}  "
            f"{worker_us:22.0f}  {r['load']:4.1f}",
            flush=True,
        )
    print("* the root's resident memory above the first size's, per vehicle more")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
