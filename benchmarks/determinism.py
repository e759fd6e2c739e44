"""Same scenario, same seed: do the runs fly the same flight, byte for byte? Any mission script, any load.

    .venv/bin/python benchmarks/determinism.py missions/square_native.py                 # max, max, x5
    .venv/bin/python benchmarks/determinism.py SCRIPT --vehicles 2 --seed 9 --busy 8      # 8 busy processes beside it
    .venv/bin/python benchmarks/determinism.py SCRIPT --speeds max,max,5 --firmware ardupilot -- --connect tcp:127.0.0.1:5760
    .venv/bin/python benchmarks/determinism.py missions/formation.py --swarm --vehicles 10 --duration 40 -- 5

Each run is ``harness run SCRIPT`` with the same seed; ``--busy N`` starts N processes that keep a core busy
for every run after the first (so the first is a reference on a quieter machine). It prints, per vehicle, the
lift-off time of every run (first sample 0.3 m above the start), whether every recorded pose is identical to
the first run's, and where the first difference is; the exit status is 0 only when all are identical.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from harness.pytest_plugin import RunRecord, run_harness

BUSY = "import time\nend = time.monotonic() + 3600\nwhile time.monotonic() < end:\n    pass\n"


def liftoff_s(track: list[dict[str, Any]]) -> float | None:
    z0 = track[0]["pos_ned_m"][2]
    return next((m["t_s"] for m in track if z0 - m["pos_ned_m"][2] > 0.3), None)


def first_difference(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> str | None:
    for x, y in zip(a, b, strict=False):
        if x != y:
            return f"t={x['t_s']} s: {x['pos_ned_m']} vs {y['pos_ned_m']}"
    if len(a) != len(b):
        return f"{len(a)} samples vs {len(b)}"
    return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("script", type=Path)
    ap.add_argument("--vehicles", type=int, default=2)
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--duration", type=float, default=120.0, help="sim-time limit of each run")
    ap.add_argument("--speeds", default="max,max,5", help="one run per entry: max or a real-time factor")
    ap.add_argument("--busy", type=int, default=0, help="busy processes beside every run after the first")
    ap.add_argument("--firmware", default=None, help="px4 (default) or ardupilot")
    ap.add_argument("--swarm", action="store_true", help="the script commands every vehicle (--swarm-mission)")
    ap.add_argument("args", nargs="*", help="the script's own arguments (after --)")
    argv = sys.argv[1:]
    cut = argv.index("--") if "--" in argv else len(argv)
    a = ap.parse_args(argv[:cut])  # argparse alone drops what follows "--" once the positionals are taken
    a.args = [*a.args, *argv[cut + 1 :]]
    extra = ["--firmware", a.firmware] if a.firmware else []
    if a.swarm:
        extra += ["--swarm-mission", str(a.script)]
    out = Path(tempfile.mkdtemp(prefix="determinism-"))
    runs: list[RunRecord] = []
    for k, speed in enumerate(a.speeds.split(",")):
        busy = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(a.busy if k else 0)]
        t0 = time.monotonic()
        try:
            run = run_harness(
                out / f"run-{k}",
                [] if a.swarm else a.script,
                vehicles=a.vehicles,
                seed=a.seed,
                speed=None if speed == "max" else float(speed),
                duration_s=a.duration,
                args=a.args,
                extra=extra,
                timeout_s=3600,
            )
        finally:
            for b in busy:
                b.kill()
                b.wait()
        codes = [v["mission_exit_code"] for v in run.summary["vehicles"]]
        load = "" if not busy else f", {len(busy)} busy processes"
        print(
            f"run {k} (speed {speed}{load}): {run.summary['status']}, sim {run.summary['sim_time_s']} s "
            f"in {time.monotonic() - t0:.1f} s, mission exits {codes}",
            flush=True,
        )
        runs.append(run)
    same = True
    for i in range(a.vehicles):
        tracks = [r.vehicle(i).track for r in runs]
        diffs = [first_difference(tracks[0], t) for t in tracks[1:]]
        same &= all(d is None for d in diffs)
        print(
            f"vehicle {i}: lift-off {[liftoff_s(t) for t in tracks]} s, identical to run 0: {[d is None for d in diffs]}"
        )
        for k, d in enumerate(diffs, start=1):
            if d is not None:
                print(f"  run {k} first differs at {d}")
    print(("BYTE-IDENTICAL" if same else "DIFFERENT") + f" ({out})")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
