"""The reference for efficiency figures: bare JSBSim instances of our quadx model at 1 kHz in one Python loop.

    .venv/bin/python benchmarks/bare_jsbsim.py 1 10 100

Machines here differ about 2.5x in speed, so full-stack figures are reported as **efficiency** too: the
full stack's real-time factor divided by the real-time factor of the same number of bare JSBSim instances
(the model of ``harness/fdm/models``, motors at hover, ``run()`` at 1 kHz, nothing else), measured in the same
session (``bench_fullstack.py`` calls :func:`bare_rtf` next to its runs). 1.0 would mean the harness costs
nothing beyond JSBSim itself.
"""

from __future__ import annotations

import sys
import time

import jsbsim

from harness.fdm.params import DEFAULT_QUAD, FT_PER_M, models_root

SUBSTEP_HZ = 1000


def _instance() -> jsbsim.FGFDMExec:
    fdm = jsbsim.FGFDMExec(str(models_root()), None)
    fdm.set_debug_level(0)
    if not fdm.load_model("quadx"):
        raise RuntimeError("JSBSim could not load the quadx model")
    fdm["ic/terrain-elevation-ft"] = 488.0 * FT_PER_M
    fdm["ic/lat-geod-deg"] = 47.397742
    fdm["ic/long-gc-deg"] = 8.545594
    fdm["ic/h-agl-ft"] = (10.0 + DEFAULT_QUAD.skid_below_cg_m) * FT_PER_M
    fdm.set_dt(1.0 / SUBSTEP_HZ)
    if not fdm.run_ic():
        raise RuntimeError("JSBSim refused the initial conditions")
    for i in range(4):
        fdm[f"fcs/motor-cmd[{i}]"] = DEFAULT_QUAD.hover_command
    return fdm


def bare_rtf(n: int, sim_s: float = 2.0) -> float:
    """Real-time factor of ``n`` bare instances stepped together at 1 kHz for ``sim_s`` of sim time."""
    fdms = [_instance() for _ in range(n)]
    runs = [f.run for f in fdms]
    steps = round(sim_s * SUBSTEP_HZ)
    t0 = time.perf_counter()
    for _ in range(steps):
        for run in runs:
            run()
    return sim_s / (time.perf_counter() - t0)


def main(argv: list[str]) -> int:
    sizes = [int(a) for a in argv] or [1, 10, 100]
    print(f"bare JSBSim quadx at {SUBSTEP_HZ} Hz, one Python loop")
    for n in sizes:
        print(f"{n:>4} vehicles: x{bare_rtf(n, 2.0 if n < 50 else 0.5):.2f} real time", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
