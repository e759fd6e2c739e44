"""Flying a flock scenario and measuring it: shared by the PX4/MAVSDK and the ArduCopter/DroneKit flock tests."""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from harness.record.world import read_topics


@dataclass(frozen=True)
class FlockFigures:
    flocking_s: float
    """Sim time during which every vehicle was up at 10 m (recorded at 50 Hz)."""
    min_separation_m: float
    max_from_centroid_m: float


def fly_scenario(scenario_toml: str, out: Path) -> Path:
    """``harness run`` of a scenario written to ``out.toml`` (400 s sim limit); it must succeed."""
    path = out.with_suffix(".toml")
    path.write_text(scenario_toml)
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", str(path), "--out", str(out), "--duration", "400"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out


def flock_figures(out: Path, vehicles: int) -> FlockFigures:
    """Horizontal separation and spread around the centroid while every vehicle is up at 10 m."""
    topics = read_topics(out / "world.mcap")
    tracks = [topics[f"/vehicle/{i}/state"] for i in range(vehicles)]
    min_sep, spread, flocking_s = math.inf, 0.0, 0.0
    for samples in zip(*tracks, strict=False):
        ps = [s["pos_ned_m"] for s in samples]
        if any(p[2] > -9.0 for p in ps):  # only while all are up at 10 m
            continue
        flocking_s += 0.02
        min_sep = min(min_sep, *(math.dist(a[:2], b[:2]) for a, b in itertools.combinations(ps, 2)))
        cn, ce = sum(p[0] for p in ps) / vehicles, sum(p[1] for p in ps) / vehicles
        spread = max(spread, *(math.hypot(p[0] - cn, p[1] - ce) for p in ps))
    return FlockFigures(flocking_s, min_sep, spread)
