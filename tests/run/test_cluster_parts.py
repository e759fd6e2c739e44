"""The pure parts of ``harness run --cluster``: the split over workers, what a worker holds, the missions'
bundle, the options; and ``--vehicles`` refused in one line when the cluster cannot hold them."""

from __future__ import annotations

import io
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from harness.core.endpoints import SYSIDS_PER_LINK, sysid
from harness.core.errors import ScenarioError
from harness.run.cluster import WorkerInfo, bundle, capacity, parse_cluster, split
from harness.run.join import JoinPlan, autopilot_groups
from harness.scenario.plan import MissionPlan


def _w(name: str, nthreads: int = 1, memory_mb: int | None = 4000, unit_s: float = 1.0) -> WorkerInfo:
    return WorkerInfo(f"tcp://{name}:1", name, nthreads, memory_mb, unit_s)


def test_split_follows_cores_over_measured_cost() -> None:
    # two cores against one, and a worker twice as slow per core: 4 : 2 : 1 of 700 vehicles
    shares = split(700, [_w("a", 2), _w("b", 1), _w("c", 1, unit_s=2.0)])
    assert [(w.host, r) for w, r in shares] == [("a", range(0, 400)), ("b", range(400, 600)), ("c", range(600, 700))]


def test_a_shared_machines_noise_does_not_skew_the_split() -> None:
    # two identical workers measured 1.2x apart under load: the same share each; 1.3x apart: 3 : 2
    assert [len(r) for _, r in split(6, [_w("a"), _w("b", unit_s=1.2)])] == [3, 3]
    assert [len(r) for _, r in split(10, [_w("a"), _w("b", unit_s=1.3)])] == [6, 4]


def test_split_is_contiguous_and_gives_no_empty_share() -> None:
    shares = split(2, [_w("a"), _w("b"), _w("c")])
    assert [r for _, r in shares] == [range(0, 1), range(1, 2)]
    shares = split(7, [_w("a"), _w("b")])
    assert [len(r) for _, r in shares] == [4, 3] and shares[1][1].start == 4


def test_split_respects_what_a_worker_holds() -> None:
    small = _w("small", 4, memory_mb=300)  # 50 MB above a share's own processes: 12 vehicles of 4 MB
    assert capacity(small, 0.0) == 12
    shares = split(100, [small, _w("big")])
    assert [len(r) for _, r in shares] == [12, 88]
    assert capacity(small, 1.0) == 0  # a mission each: 84 MB a vehicle


def test_system_ids_are_unique_on_every_ground_station_port() -> None:
    assert [sysid(v) for v in (0, 1, 243, 244, 499)] == [1, 2, 244, 1, 12]
    plan = JoinPlan(parent="tcp://x:1", first_vehicle=250, vehicles=500, out=Path("."), processes=1)
    groups = autopilot_groups(plan)
    assert len(groups) == 3 and groups[0].start == 250 and groups[-1].stop == 750
    for g in groups:  # each autopilot process has a port of its own: ids within one must not repeat
        assert len(g) <= SYSIDS_PER_LINK and len({sysid(v) for v in g}) == len(g)


def test_the_missions_directories_travel_in_one_tar(tmp_path: Path) -> None:
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "fly.py").write_text("print('hi')\n")
    (tmp_path / "m" / "waypoints.csv").write_text("0,0,10\n")
    (tmp_path / "m" / "__pycache__").mkdir()
    (tmp_path / "m" / "__pycache__" / "fly.cpython-311.pyc").write_bytes(b"x")
    data, rel = bundle([MissionPlan(tmp_path / "m" / "fly.py", ("3",)), None])
    assert rel == [("d0/fly.py", ("3",)), None]
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        names = sorted(m.name for m in tar.getmembers() if m.isfile())
    assert names == ["d0/fly.py", "d0/waypoints.csv"]


@pytest.mark.parametrize("text", ["local", "local:0", "local:x", "tcp://h:1"])
def test_bad_cluster_option_is_one_line(text: str) -> None:
    with pytest.raises(ScenarioError, match="--cluster must be local:K"):
        parse_cluster(text)


def test_more_vehicles_than_the_cluster_holds_is_one_line(tmp_path: Path) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "harness.cli",
            "run",
            "--vehicles",
            "900000",
            "--cluster",
            "local:1",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("harness: --vehicles 900000: the cluster's 1 worker(s) hold "), lines
