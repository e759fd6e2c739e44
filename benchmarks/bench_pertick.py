"""Per-vehicle-tick cost by component, robust to a loaded machine: the median of each component's per-call time.

    .venv/bin/python benchmarks/bench_pertick.py [--vehicles 10] [--seconds 10]

Every vehicle arms, takes off to 5 m and hovers in wind with turbulence (physics, sensors, autopilot in one
loop, as ``harness run`` steps them in its process), with a ULog per vehicle and ``world.mcap`` written as a run
writes them (the recording at 50 Hz). Each component is timed per call with ``perf_counter_ns``; a call that
the scheduler interrupted is an outlier, so the **median** is reported (a sum of wall times on a shared
machine measures the other users too). Figures are µs per vehicle per tick (250 Hz); the recording's per call
of 50 Hz is divided by 5. Nested components are shown exclusive of the ones listed under them.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from harness.autopilot.api import FlightMode
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.estimator import Estimator
from harness.autopilot.flight import FlightCore
from harness.autopilot.flightlog import FlightLog
from harness.core import native
from harness.fdm.environment import WindConfig
from harness.fdm.physics import Physics, PhysicsConfig
from harness.fdm.sensors import SensorModel
from harness.record.sample import VehicleSample
from harness.record.world import WorldRecorder

TIMES: dict[str, list[int]] = defaultdict(list)


def _timed(cls: type, name: str, label: str) -> None:
    """Wrap ``cls.name`` so that every call's duration is kept under ``label``."""
    inner: Callable[..., Any] = getattr(cls, name)
    perf = time.perf_counter_ns
    out = TIMES[label]

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = perf()
        r = inner(*args, **kwargs)
        out.append(perf() - t0)
        return r

    setattr(cls, name, wrapper)


def _median_us(label: str) -> float:
    return statistics.median(TIMES[label]) / 1e3 if TIMES[label] else 0.0


def measure(n: int, seconds: float) -> dict[str, float]:
    for cls, name, label in (
        (Physics, "step", "physics"),
        (Physics, "_frame", "frame"),
        (SensorModel, "sample", "sensors"),
        (Autopilot, "step", "autopilot"),
        (FlightCore, "step", "core"),
        (Estimator, "update", "estimator"),
        (FlightCore, "_control", "control"),
        (FlightLog, "record", "ulog"),
        (WorldRecorder, "vehicle", "world"),
    ):
        _timed(cls, name, label)
    wind = WindConfig(steady_ned_m_s=(2.0, -1.0, 0.0), turbulence="moderate")
    phys = Physics(PhysicsConfig(n_vehicles=n, seed=1, wind=wind))
    aps = [Autopilot(AutopilotConfig(vehicle=v)) for v in range(n)]
    with tempfile.TemporaryDirectory() as tmp:
        for ap in aps:
            ap.flight_log = FlightLog(Path(tmp) / f"vehicle-{ap.vehicle}.ulg", ap.params, ap.vehicle, 0)
        world = WorldRecorder(Path(tmp) / "world.mcap", 0, n)
        frames = phys.frames()
        warm = 250 * 15
        for tick in range(warm + round(seconds * 250)):
            if tick == warm:
                for kept in TIMES.values():
                    kept.clear()
            motors = [ap.step(f) for ap, f in zip(aps, frames, strict=True)]
            frames = phys.step(motors)
            if tick % 5 == 0:
                for f, m in zip(frames, motors, strict=True):
                    t = f.truth
                    world.vehicle(
                        VehicleSample(
                            f.t_ns, f.vehicle, t.pos_ned_m, t.quat, t.vel_ned_m_s, t.lat_deg, t.lon_deg,
                            t.alt_amsl_m, m, t.on_ground, t.crashed,
                        )
                    )  # fmt: skip
            if tick % 25 == 0 and tick < warm:
                for ap in aps:
                    if not ap.telemetry.state().armed and ap.telemetry.arming_check() == "":
                        ap.action.arm()
                        ap.action.takeoff(5.0)
        hovering = sum(ap.telemetry.state().mode == FlightMode.HOLD for ap in aps)
        for ap in aps:
            assert ap.flight_log is not None
            ap.flight_log.close()
        world.close()
    physics, frame, sensors = _median_us("physics") / n, _median_us("frame"), _median_us("sensors")
    autopilot, core, ulog = _median_us("autopilot"), _median_us("core"), _median_us("ulog")
    estimator, control = _median_us("estimator"), _median_us("control")
    return {
        "JSBSim run() and commands": physics - frame,
        "frame: property reads, truth": frame - sensors,
        "sensors": sensors,
        "estimator": estimator,
        "control: navigator, position, attitude, rate, mixer": control,
        "flight core, rest (battery, land detector)": core - estimator - control,
        "ULog": ulog,
        "autopilot, rest (lock, failures, manual, supervisor, bell check)": autopilot - core - ulog,
        "world.mcap (per tick: per 50 Hz sample / 5)": _median_us("world") / 5,
        "hovering vehicles": float(hovering),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=10.0, help="measured sim seconds of hover")
    args = ap.parse_args()
    if native.ACTIVE:
        sys.exit(
            "bench_pertick.py wraps methods of classes that are compiled here (harness.core.native): run it with "
            "HARNESS_PURE=1 (the pure-Python core), or benchmarks/bench_core.py for the compiled one"
        )
    r = measure(args.vehicles, args.seconds)
    hovering = r.pop("hovering vehicles")
    print(f"{args.vehicles} vehicles ({hovering:.0f} hovering), {args.seconds:g} s of sim; median µs per vehicle-tick")
    for label, us in r.items():
        print(f"  {label:66s} {us:7.2f}")
    jsb = r["JSBSim run() and commands"]
    rest = sum(r.values()) - jsb
    print(f"  {'everything but JSBSim':66s} {rest:7.2f}  ({rest / jsb:.2f} x JSBSim)")


if __name__ == "__main__":
    main()
