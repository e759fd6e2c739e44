"""Acceptance (issue 6): five vehicles flock over the built-in radio for 120 s of sim time; with the network
dropping everything, the same flock measurably falls apart."""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
from pathlib import Path

import pytest

from harness.record.world import read_topics

pytestmark = pytest.mark.sim
FLOCK = Path(__file__).resolve().parents[2] / "missions" / "flock.py"


def fly(tmp_path: Path, name: str, max_range_m: float) -> tuple[float, float]:
    scenario = tmp_path / f"{name}.toml"
    scenario.write_text(
        f'[vehicles]\ncount = 5\nmission = "{FLOCK}"\nargs = ["120"]\n'
        f'[network]\nmodel = "builtin"\nparams = {{ max_range_m = {max_range_m} }}\n'
    )
    out = tmp_path / name
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", str(scenario), "--out", str(out), "--duration", "400"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    topics = read_topics(out / "world.mcap")
    tracks = [topics[f"/vehicle/{i}/state"] for i in range(5)]
    min_sep, max_from_centroid, flocking_s = math.inf, 0.0, 0.0
    for samples in zip(*tracks, strict=False):
        ps = [s["pos_ned_m"] for s in samples]
        if any(p[2] > -9.0 for p in ps):  # only while all five are up at 10 m
            continue
        flocking_s += 0.02
        min_sep = min(min_sep, *(math.dist(a[:2], b[:2]) for a, b in itertools.combinations(ps, 2)))
        cn, ce = sum(p[0] for p in ps) / 5, sum(p[1] for p in ps) / 5
        max_from_centroid = max(max_from_centroid, *(math.hypot(p[0] - cn, p[1] - ce) for p in ps))
    print(
        f"FIGURE flock {name}: {flocking_s:.0f} s, min separation {min_sep:.2f} m, max from centroid {max_from_centroid:.2f} m"
    )
    assert flocking_s >= 120.0
    return min_sep, max_from_centroid


def test_flock_holds_over_the_radio_and_falls_apart_without_it(tmp_path: Path) -> None:
    sep, spread = fly(tmp_path, "radio", 2000.0)
    assert sep > 2.0 and spread < 30.0
    sep_off, spread_off = fly(tmp_path, "silent", 0.5)
    assert spread_off > 2 * spread and sep_off < sep  # measurably worse on both
