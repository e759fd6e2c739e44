"""The per-vehicle core's cost per call, compiled (mypyc, ``harness.core.native``) or not: the median of every
``Autopilot.step`` and ``Physics.step`` over a hover, robust to a shared machine.

    .venv/bin/python benchmarks/bench_core.py 1 10                      # whatever this process runs
    .venv/bin/python benchmarks/bench_core.py 1 10 --rounds 2 --ab      # compiled and pure, interleaved

Each vehicle arms, takes off to 5 m (no wind) and hovers; the calls after 12 s of sim are timed with
``perf_counter_ns`` per tick and divided by the number of vehicles. Figures are µs per vehicle-tick (250 Hz;
a tick is 4 ms of sim). ``--ab`` runs every size in fresh processes, compiled and with ``HARNESS_PURE=1``
(pure Python: numba's kernels from two vehicles in a process, as ``harness run`` chooses), one after the
other, ``--rounds`` times.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def measure(n: int, seconds: float) -> str:
    from harness.core import jit, native

    jit.prefer(n >= 2)  # as harness run chooses (harness.run.launcher), before the kernels' modules are imported
    from harness.autopilot.autopilot import Autopilot, AutopilotConfig
    from harness.fdm.physics import Physics, PhysicsConfig

    phys = Physics(PhysicsConfig(n_vehicles=n, seed=3))
    aps = [Autopilot(AutopilotConfig(vehicle=v)) for v in range(n)]
    frames = phys.frames()
    ap_us: list[float] = []
    ph_us: list[float] = []
    clock = time.perf_counter_ns
    settle = 12 * 250
    for tick in range(settle + round(seconds * 250)):
        t0 = clock()
        motors = [ap.step(f) for ap, f in zip(aps, frames, strict=True)]
        t1 = clock()
        frames = phys.step(motors)
        t2 = clock()
        if tick >= settle:
            ap_us.append((t1 - t0) / n / 1000)
            ph_us.append((t2 - t1) / n / 1000)
        if tick % 25 == 0:
            for ap in aps:
                if not ap.telemetry.state().armed and ap.telemetry.arming_check() == "":
                    ap.action.arm()
                    ap.action.takeoff(5.0)
    mode = "compiled" if native.ACTIVE else ("pure+numba" if jit.ENABLED else "pure")
    return (
        f"{mode:>10} {n:>4} vehicles: Autopilot.step {statistics.median(ap_us):6.2f}  "
        f"Physics.step {statistics.median(ph_us):6.2f} µs/vehicle-tick (median)  altitude "
        f"{-frames[0].truth.pos_ned_m[2]:.3f} m"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="*", type=int, default=[1, 10])
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds of hover timed")
    ap.add_argument("--ab", action="store_true", help="compiled and HARNESS_PURE=1, interleaved, fresh processes")
    ap.add_argument("--rounds", type=int, default=1)
    a = ap.parse_args()
    if not a.ab:
        for n in a.sizes:
            print(measure(n, a.seconds), flush=True)
        return 0
    base = {k: v for k, v in os.environ.items() if k != "HARNESS_PURE"}
    for r in range(a.rounds):
        with open("/proc/loadavg") as f:
            print(f"round {r + 1}, load average {' '.join(f.read().split()[:3])}", flush=True)
        for n in a.sizes:
            for env in (base, base | {"HARNESS_PURE": "1"}):
                cmd = [sys.executable, str(Path(__file__).resolve()), str(n), "--seconds", str(a.seconds)]
                out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
                print(out.stdout.strip().splitlines()[-1], flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
