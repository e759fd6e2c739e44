"""Autopilot benchmark: cost per vehicle per tick, and real-time factor of physics + autopilot (+ lockstep).

Run: ``.venv/bin/python benchmarks/bench_autopilot.py [--seconds 20] [--vehicles 1 10] [--no-channel]``

Every vehicle arms, takes off to 5 m with its sensor-based estimator and hovers; the measured window
starts once all are hovering. Figures:
- in-process loop (Physics.step + Autopilot.step, no sockets): autopilot and physics µs per vehicle-tick, RTF;
- lockstep (the shipped layout of ``harness run``): the same through the root channel in the physics process,
  autopilots stepped by it in-process, phases every 5th tick — RTF (targets: >= 50x for 1, >= 5x for 10);
- through the lockstep channel (TCP loopback; not with ``--no-channel``): autopilots in separate processes —
  one host process for all vehicles, and one process per vehicle — RTF of each layout.
Numbers are wall-clock on a shared machine: noisy when other work runs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

from harness.autopilot.api import FlightMode
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.channel import Channel, ChannelConfig
from harness.fdm.frame import encode_frame
from harness.fdm.physics import Physics, PhysicsConfig
from harness.wire import protocol as p

TICK_HZ = 250
SUBSTEP_HZ = 1000
"""The shipped defaults (scenario launcher); ``--physics-hz`` / ``--tick-hz`` change them for a run."""
ALT_M = 5.0


RATES = {"physics_hz": float(SUBSTEP_HZ), "tick_hz": float(TICK_HZ)}


def _physics(n: int) -> Physics:
    return Physics(PhysicsConfig(n_vehicles=n, seed=0, substep_hz=RATES["physics_hz"], tick_hz=RATES["tick_hz"]))


def in_process(n: int, seconds: float) -> dict[str, float]:
    tick_hz = round(RATES["tick_hz"])
    phys = _physics(n)
    aps = [Autopilot(AutopilotConfig(vehicle=v)) for v in range(n)]
    frames = phys.frames()
    # get everyone up (not measured)
    for ticks in range(1, tick_hz * 25):
        frames = phys.step([ap.step(f) for ap, f in zip(aps, frames, strict=True)])
        if ticks % 25 == 0:
            for ap in aps:
                s = ap.telemetry.state()
                if not s.armed and ap.telemetry.arming_check() == "":
                    ap.action.arm()
                    ap.action.takeoff(ALT_M)
        if ticks > tick_hz * 3 and all(
            ap.telemetry.state().mode == FlightMode.HOLD and ap.telemetry.state().armed for ap in aps
        ):
            break
    assert all(ap.telemetry.state().armed for ap in aps), [ap.telemetry.arming_check() for ap in aps]
    n_ticks = round(seconds * tick_hz)
    ap_ns = 0
    perf = time.perf_counter_ns
    t0 = perf()
    for _ in range(n_ticks):
        a = perf()
        motors = [ap.step(f) for ap, f in zip(aps, frames, strict=True)]
        ap_ns += perf() - a
        frames = phys.step(motors)
    wall_ns = perf() - t0
    alts = [-f.truth.pos_ned_m[2] for f in frames]
    return {
        "autopilot_us_per_vehicle_tick": ap_ns / 1e3 / (n_ticks * n),
        "physics_us_per_vehicle_tick": (wall_ns - ap_ns) / 1e3 / (n_ticks * n),
        "rtf": seconds / (wall_ns / 1e9),
        "min_alt_m": min(alts),
        "max_alt_m": max(alts),
    }


def with_lockstep_core(n: int, seconds: float) -> dict[str, float]:
    """The shipped layout of ``harness run``: physics owns the root channel (``attach_physics``) and steps the
    autopilots inside its process through it (``NativeLink``, ``attach_local_autopilots``) with the shipped
    phase period (every 5th tick); no missions or network are attached, so phases are empty."""
    from harness.run.link import NativeLink

    tick_hz = round(RATES["tick_hz"])
    ch = Channel(ChannelConfig(tick_hz=tick_hz, phase_every=5, stall_timeout_s=30))
    ch.attach_physics()
    phys = _physics(n)
    aps = {v: Autopilot(AutopilotConfig(vehicle=v)) for v in range(n)}
    link = NativeLink(ch, aps)
    frames = phys.frames()
    try:
        for ticks in range(1, tick_hz * 25):
            etas = link.exchange(phys.t_ns, phys.tick, frames)
            frames = phys.step([e.motors for e in etas])
            if ticks % 25 == 0:
                for ap in aps.values():
                    if not ap.telemetry.state().armed and ap.telemetry.arming_check() == "":
                        ap.action.arm()
                        ap.action.takeoff(ALT_M)
            if ticks > tick_hz * 3 and all(
                ap.telemetry.state().mode == FlightMode.HOLD and ap.telemetry.state().armed for ap in aps.values()
            ):
                break
        n_ticks = round(seconds * tick_hz)
        t0 = time.perf_counter_ns()
        for _ in range(n_ticks):
            etas = link.exchange(phys.t_ns, phys.tick, frames)
            frames = phys.step([e.motors for e in etas])
        wall_ns = time.perf_counter_ns() - t0
    finally:
        ch.close("benchmark done")
    alts = [-f.truth.pos_ned_m[2] for f in frames]
    return {"rtf": seconds / (wall_ns / 1e9), "min_alt_m": min(alts), "max_alt_m": max(alts)}


def through_channel(n: int, seconds: float, per_vehicle_process: bool) -> dict[str, float]:
    """Root channel inside this (physics) process, autopilot hosts as separate processes over TCP."""
    tick_hz = round(RATES["tick_hz"])
    ch = Channel(ChannelConfig(address="tcp://127.0.0.1:0", tick_hz=tick_hz, stall_timeout_s=30))
    ch.attach_physics()
    groups = [[v] for v in range(n)] if per_vehicle_process else [list(range(n))]
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "harness.autopilot.host",
                "--address",
                ch.address,
                "--vehicles",
                ",".join(map(str, g)),
                "--takeoff-alt",
                str(ALT_M),
            ],
            env=dict(os.environ),
        )
        for g in groups
    ]
    try:
        if not ch.wait_for(lambda subs: len(subs) == len(procs), 60):
            raise RuntimeError("autopilot hosts did not join within 60 s")
        phys = _physics(n)
        frames = phys.frames()
        warm = tick_hz * 20
        total = warm + round(seconds * tick_hz)
        t0 = 0
        for k in range(total):
            if k == warm:
                t0 = time.perf_counter_ns()
            etas = ch.step(
                [p.BeginTickAC(f.t_ns, k, v, n, f.truth.pos_ned_m, encode_frame(f)) for v, f in enumerate(frames)]
            )
            motors: list[tuple[float, ...]] = [()] * n
            for e in etas:
                motors[e.vehicle] = e.motors
            frames = phys.step(motors)
        wall_ns = time.perf_counter_ns() - t0
        alts = [-f.truth.pos_ned_m[2] for f in frames]
    finally:
        ch.close("benchmark done")
        for pr in procs:
            try:
                pr.wait(10)
            except subprocess.TimeoutExpired:
                pr.kill()
    return {"rtf": seconds / (wall_ns / 1e9), "min_alt_m": min(alts), "max_alt_m": max(alts)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="measured sim seconds of hover")
    ap.add_argument("--vehicles", type=int, nargs="+", default=[1, 10])
    ap.add_argument("--no-channel", action="store_true")
    ap.add_argument("--physics-hz", type=float, default=SUBSTEP_HZ)
    ap.add_argument("--tick-hz", type=int, default=TICK_HZ)
    args = ap.parse_args()
    RATES["physics_hz"], RATES["tick_hz"] = args.physics_hz, float(args.tick_hz)
    print(
        f"rates: physics sub-step {args.physics_hz:g} Hz, control tick {args.tick_hz} Hz; hover at {ALT_M} m, "
        f"{args.seconds:g} s of sim time measured; machine shared (noisy)"
    )
    for n in args.vehicles:
        r = in_process(n, args.seconds)
        print(
            f"in-process  {n:3d} vehicle(s): autopilot {r['autopilot_us_per_vehicle_tick']:6.1f} us/vehicle/tick, "
            f"physics {r['physics_us_per_vehicle_tick']:6.1f} us/vehicle/tick, RTF {r['rtf']:7.1f}x "
            f"(alt {r['min_alt_m']:.2f}-{r['max_alt_m']:.2f} m)"
        )
        r = with_lockstep_core(n, args.seconds)
        print(
            f"lockstep    {n:3d} vehicle(s), shipped layout (root channel in physics, autopilots in-process): "
            f"RTF {r['rtf']:7.1f}x (alt {r['min_alt_m']:.2f}-{r['max_alt_m']:.2f} m)"
        )
        if args.no_channel:
            continue
        layouts = [False, True] if n > 1 else [False]
        for per_vehicle in layouts:
            r = through_channel(n, args.seconds, per_vehicle)
            label = "process per vehicle" if per_vehicle else "one host process  "
            print(
                f"channel     {n:3d} vehicle(s), {label}: RTF {r['rtf']:7.1f}x "
                f"(alt {r['min_alt_m']:.2f}-{r['max_alt_m']:.2f} m)"
            )


if __name__ == "__main__":
    main()
