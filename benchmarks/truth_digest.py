"""Determinism guard for speed work: a digest of every tick's sensor frame and motor commands of a fixed-seed
in-process flight (physics + sensors + autopilot, wind and turbulence on), and the largest difference to a
saved reference.

    .venv/bin/python benchmarks/truth_digest.py --save ref.npz      # before a change
    .venv/bin/python benchmarks/truth_digest.py --compare ref.npz   # after: digest equal? max |Δ| per field

Each vehicle arms, takes off to 5 m, flies to a point 6 m north-east and hovers there; the frames (IMU,
truth, mag, baro, GPS as encoded for the wire) and the motors are hashed, and the ground-truth positions and
motor commands are kept as float64 arrays so that a change that only reorders arithmetic shows its size.
"""

from __future__ import annotations

import argparse
import hashlib
import sys

import numpy as np

from harness.autopilot.api import FlightMode
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.fdm.environment import WindConfig
from harness.fdm.frame import encode_frame
from harness.fdm.physics import Physics, PhysicsConfig


def fly(n: int, seconds: float, seed: int) -> tuple[str, np.ndarray, np.ndarray]:
    wind = WindConfig(steady_ned_m_s=(2.0, -1.0, 0.0), turbulence="moderate")
    phys = Physics(PhysicsConfig(n_vehicles=n, seed=seed, wind=wind))
    aps = [Autopilot(AutopilotConfig(vehicle=v)) for v in range(n)]
    frames = phys.frames()
    digest = hashlib.sha256()
    pos: list[tuple[float, ...]] = []
    mot: list[tuple[float, ...]] = []
    moved = [False] * n
    for tick in range(round(seconds * 250)):
        motors = [ap.step(f) for ap, f in zip(aps, frames, strict=True)]
        for f, m in zip(frames, motors, strict=True):
            digest.update(encode_frame(f))
            digest.update(np.asarray(m, dtype=np.float64).tobytes())
            pos.append(f.truth.pos_ned_m)
            mot.append(tuple(m))
        frames = phys.step(motors)
        if tick % 25 == 0:
            for i, ap in enumerate(aps):
                s = ap.telemetry.state()
                if not s.armed and ap.telemetry.arming_check() == "":
                    ap.action.arm()
                    ap.action.takeoff(5.0)
                elif s.armed and s.mode == FlightMode.HOLD and not moved[i] and tick > 250 * 12:
                    lat, lon, _ = phys.cfg.origin.ned_to_geodetic(6.0, 6.0, 0.0)
                    ap.action.reposition(lat, lon, None)
                    moved[i] = True
    return digest.hexdigest(), np.asarray(pos, dtype=np.float64), np.asarray(mot, dtype=np.float64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--save", help="write the reference here (.npz)")
    ap.add_argument("--compare", help="compare with this reference (.npz)")
    args = ap.parse_args()
    digest, pos, mot = fly(args.vehicles, args.seconds, args.seed)
    print(f"digest {digest}  final positions {pos[-args.vehicles :].round(3).tolist()}")
    if args.save:
        np.savez(args.save, digest=digest, pos=pos, mot=mot)
    if args.compare:
        ref = np.load(args.compare)
        same = str(ref["digest"]) == digest
        dpos = float(np.max(np.abs(ref["pos"] - pos))) if ref["pos"].shape == pos.shape else float("inf")
        dmot = float(np.max(np.abs(ref["mot"] - mot))) if ref["mot"].shape == mot.shape else float("inf")
        print(f"identical digest: {same}; max |Δ position| {dpos:.3g} m, max |Δ motor| {dmot:.3g}")
        sys.exit(0 if same else 1)


if __name__ == "__main__":
    main()
