"""``harness run --workers N``: the vehicles' autopilots spread over processes; the same ground truth (issue 13)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from harness.core.errors import ScenarioError
from harness.record.world import read_topics
from harness.run.tree import parse_workers, worker_groups
from tests.run.flights import MISSIONS


def test_worker_groups_cover_every_vehicle_once_in_equal_shares() -> None:
    assert worker_groups(10, 3) == [range(0, 4), range(4, 7), range(7, 10)]
    assert worker_groups(2, 8) == [range(0, 1), range(1, 2)]  # never an empty worker
    assert worker_groups(5, 1) == [range(0, 5)]
    assert parse_workers("3") == 3 and parse_workers("auto") >= 1
    with pytest.raises(ScenarioError, match="--workers must be >= 1"):
        parse_workers("0")
    with pytest.raises(ScenarioError, match="'auto', got 'many'"):
        parse_workers("many")


def _fly(out: Path, workers: int) -> dict[str, list[dict[str, object]]]:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "harness.cli",
            "run",
            "--no-progress",
            "--vehicles",
            "4",
            "--mission",
            str(MISSIONS / "pymavlink_takeoff.py"),
            "--seed",
            "5",
            "--workers",
            str(workers),
            "--duration",
            "60",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert [v["mission_exit_code"] for v in summary["vehicles"]] == [0] * 4
    return read_topics(out / "world.mcap")


@pytest.mark.sim
def test_same_ground_truth_with_one_or_three_workers(tmp_path: Path) -> None:
    """pymavlink missions (byte-reproducible, docs/simclock.md) on 4 vehicles, seed 5: every recorded pose
    of every vehicle agrees to 1 mm whether all autopilots run in `harness run` or over 3 processes."""
    one = _fly(tmp_path / "one", 1)
    three = _fly(tmp_path / "three", 3)
    assert sorted((tmp_path / "three").glob("autopilot*.stderr")) == [
        tmp_path / "three" / "autopilot-1.stderr",
        tmp_path / "three" / "autopilot.stderr",
    ]
    for i in range(4):
        a, b = one[f"/vehicle/{i}/state"], three[f"/vehicle/{i}/state"]
        assert len(a) == len(b) > 500
        assert max(-float(s["pos_ned_m"][2]) for s in a) > 2.0  # it flew  # type: ignore[index]
        worst = max(math.dist(x["pos_ned_m"], y["pos_ned_m"]) for x, y in zip(a, b, strict=True))  # type: ignore[arg-type]
        assert worst < 1e-3, f"vehicle {i}: tracks differ by {worst * 1000:.2f} mm"
