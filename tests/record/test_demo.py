"""The Quickstart demo (``harness demo``): three vehicles flock over the radio to a waypoint 72 m away and
home again, land, and the command ends by printing how to open the 3D view."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from harness.record.world import read_topics

pytestmark = pytest.mark.sim


def test_the_demo_swarm_flies_out_together_and_home(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "demo", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == f"3D view: harness view {out}" or "not recorded" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    topics = read_topics(out / "world.mcap")
    tracks = [[s["pos_ned_m"] for s in topics[f"/vehicle/{i}/state"]] for i in range(3)]
    for i, track in enumerate(tracks):
        start = track[0]
        far = max(math.dist(p[:2], start[:2]) for p in track)
        assert far > 60.0, f"vehicle {i} got only {far:.1f} m from its spawn point"
        assert math.dist(track[-1][:2], start[:2]) < 10.0 and summary["vehicles"][i]["landed"]
    airborne = [ps for ps in zip(*tracks, strict=False) if all(p[2] < -5.0 for p in ps)]
    spread = max(math.dist(a[:2], b[:2]) for ps in airborne for a, b in itertools.combinations(ps, 2))
    closest = min(math.dist(a, b) for ps in airborne for a, b in itertools.combinations(ps, 2))
    print(f"FIGURE demo: {summary['sim_time_s']:.1f} s sim in {summary['wall_time_s']:.1f} s; spread {spread:.1f} m")
    assert spread < 25.0 and closest > 1.5  # together, and never into each other
