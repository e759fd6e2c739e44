"""Acceptance (issue 15): ``world.rrd`` of a 2-vehicle run loads with Rerun's Python API and holds every
vehicle's pose for the whole run, the same poses as ``world.mcap``; plus what the view holds beyond poses."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest

from harness.record.world import read_topics

pytestmark = pytest.mark.sim
ROOT = Path(__file__).resolve().parents[2]

rerun = pytest.importorskip("rerun", reason="the view extra is not installed (pip install 'uav-harness[view]')")


def read_rrd(path: Path) -> dict[str, dict[str, list[Any]]]:
    """Every temporal column of every entity: {entity: {"sim_time": [s...], "Archetype:field": [...]}}."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list[Any]]] = defaultdict(lambda: defaultdict(list))
    for chunk in RrdReader(path).stream():
        if chunk.is_static or "sim_time" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name in ("rerun.controls.RowId", "log_time", "log_tick"):
                continue
            if name == "sim_time":  # a duration in ns
                values = [ns / 1e9 for ns in batch.column(name).cast("int64").to_pylist()]
            else:
                values = batch.column(name).to_pylist()
            out[chunk.entity_path][name].extend(values)
    return out


@pytest.mark.parametrize("workers", [1, 2])
def test_world_rrd_of_a_two_vehicle_run_holds_every_pose(tmp_path: Path, workers: int) -> None:
    """With 2 workers vehicle 1 is simulated and flown in an autopilot host: its label (mode, armed) comes
    from the status its host reports each tick."""
    out = tmp_path / "run"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "harness.cli",
            "run",
            "--vehicles",
            "2",
            "--out",
            str(out),
            "--network",
            "builtin",
            "--mission",
            str(ROOT / "missions" / "takeoff_and_land.py"),
            "--workers",
            str(workers),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"3D view: harness view {out}" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    sim_s = summary["sim_time_s"]
    rrd = read_rrd(out / "world.rrd")
    mcap = read_topics(out / "world.mcap")
    for i in range(2):
        body = rrd[f"/world/vehicle/{i}"]
        t = body["sim_time"]
        pos = [row[0] for row in body["Transform3D:translation"]]  # one instance per row
        quat = [row[0] for row in body["Transform3D:quaternion"]]
        assert len(t) == len(pos) == len(quat)
        assert t == sorted(t) and t[0] == 0.0 and t[-1] >= sim_s - 0.05, (t[0], t[-1], sim_s)
        assert max(b - a for a, b in itertools.pairwise(t)) <= 0.021  # 50 Hz, no gap
        poses = mcap[f"/vehicle/{i}/pose"]
        assert len(poses) == len(t)
        for k in (0, len(t) // 2, len(t) - 1):  # the same truth as world.mcap: position and attitude
            p, q = poses[k]["pose"]["position"], poses[k]["pose"]["orientation"]
            assert pos[k] == pytest.approx([p["x"], p["y"], p["z"]], abs=1e-4)
            assert quat[k] == pytest.approx([q["x"], q["y"], q["z"], q["w"]], abs=1e-5)
        alt = max(-z for _, _, z in pos)
        assert alt == pytest.approx(summary["vehicles"][i]["max_altitude_m"], abs=0.1)
    # beyond poses: series, labels with the flight mode, home points, the map track
    assert len(rrd["/series/altitude_m"]["Scalars:scalars"]) == len(rrd["/world/vehicle/0"]["sim_time"])
    for i in range(2):
        labels = {lab for row in rrd[f"/world/vehicle/{i}/body"]["Boxes3D:labels"] for lab in row}
        assert {f"vehicle {i} TAKEOFF armed", f"vehicle {i} LAND armed"} <= labels, labels
    # the modes are sampled as the run records (every 0.2 s of sim), not once per batch of seconds: the label
    # says TAKEOFF by the time the vehicle leaves the ground, and LAND by the time it starts to come down
    first: dict[str, float] = {}
    body = rrd["/world/vehicle/0/body"]
    for t_s, row in zip(body["sim_time"], body["Boxes3D:labels"], strict=True):
        first.setdefault(row[0], t_s)
    track = list(
        zip(rrd["/world/vehicle/0"]["sim_time"], rrd["/world/vehicle/0"]["Transform3D:translation"], strict=True)
    )
    liftoff = next(t for t, p in track if -p[0][2] > 0.5)
    top_t, top_p = max(track, key=lambda tp: -tp[1][0][2])
    descent = next(t for t, p in track if t > top_t and -p[0][2] < -top_p[0][2] - 0.5)
    assert first["vehicle 0 TAKEOFF armed"] <= liftoff, (first, liftoff)
    assert first["vehicle 0 LAND armed"] <= descent, (first, descent)
    # home points come from the autopilots in this process (a host's vehicles have none in the view)
    assert len(rrd["/world/home"]["Points3D:positions"][-1]) == 2 // workers
    assert len(rrd["/map/vehicles"]["GeoPoints:positions"][0]) == 2
