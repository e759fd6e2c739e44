"""Full-stack benchmark: real-time factor of `harness run` with physics, autopilots, the built-in network
and one MAVSDK mission process per vehicle (`missions/hover.py`: take off, hover 30 s, land, broadcasting
its position over the radio at 10 Hz and reading what the others send), at the shipped default rates
(physics 1 kHz, control tick 250 Hz, phases 0/1 every 5th tick = 50 Hz).

    .venv/bin/python benchmarks/bench_fullstack.py            # 1, 10 and 50 vehicles
    .venv/bin/python benchmarks/bench_fullstack.py 1 10       # chosen sizes

Targets (issue 7, 2-core machine): >= 30x for 1 vehicle, >= 3x for 10, >= 0.5x for 50.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {1: 30.0, 10: 3.0, 50: 0.5}
BEACON_HZ = 10.0


def run(vehicles: int, hover_s: float) -> dict[str, float]:
    out = Path(tempfile.mkdtemp(prefix=f"bench-fullstack-{vehicles}-"))
    cmd = [
        sys.executable,
        "-m",
        "harness.cli",
        "run",
        "--vehicles",
        str(vehicles),
        "--network",
        "builtin",
        "--mission",
        str(ROOT / "missions" / "hover.py"),
        "--out",
        str(out),
        "--",
        str(hover_s),
        str(BEACON_HZ),
    ]
    start = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    wall = time.monotonic() - start
    summary = json.loads((out / "summary.json").read_text())
    if proc.returncode != 0:
        print(f"  run of {vehicles} failed ({summary.get('message')}); see {out}", file=sys.stderr)
    return {
        "sim_s": summary["sim_time_s"],
        "wall_s": summary["wall_time_s"],
        "rtf": summary["real_time_factor"],
        "process_wall_s": wall,
        "ok": float(proc.returncode == 0),
    }


def main() -> int:
    sizes = [int(a) for a in sys.argv[1:]] or [1, 10, 50]
    print(
        "full stack: JSBSim physics + autopilots + MAVLink + built-in network + 1 MAVSDK (gRPC API) mission per vehicle"
    )
    print("rates: physics 1000 Hz, tick 250 Hz, phase 0/1 at 50 Hz; mission: takeoff, hover 30 s, land; 10 Hz beacons")
    print(f"{'vehicles':>8} {'sim s':>7} {'wall s':>7} {'RTF':>7} {'target':>7} {'ok':>3}")
    for n in sizes:
        r = run(n, 30.0)
        target = TARGETS.get(n)
        print(
            f"{n:>8} {r['sim_s']:>7.1f} {r['wall_s']:>7.1f} {r['rtf']:>6.1f}x {target or 0:>6.1f}x {int(r['ok']):>3}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
