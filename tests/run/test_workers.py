"""``harness run --workers N``: the vehicles' autopilots spread over processes; the same ground truth (issue 13)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.core.errors import ScenarioError, SimulationError
from harness.record.world import read_topics
from harness.run.ledger import Ledger, Row
from harness.run.tree import AUTO, auto_workers, parse_workers, worker_groups
from harness.wire import protocol as p
from tests.run.flights import MISSIONS, wait_for_sim_time
from tests.run.test_run import harness, pids_with_run_dir


def test_worker_groups_cover_every_vehicle_once_in_equal_shares() -> None:
    assert worker_groups(10, 3) == [range(0, 4), range(4, 7), range(7, 10)]
    assert worker_groups(2, 8) == [range(0, 1), range(1, 2)]  # never an empty worker
    assert worker_groups(5, 1) == [range(0, 5)]
    assert parse_workers("3") == 3 and parse_workers("auto") == AUTO
    # auto: one process per core, each with at least 2 vehicles; 1 vehicle is always 1 process
    assert [auto_workers(n, cores=2) for n in (1, 2, 3, 4, 10, 100)] == [1, 1, 1, 2, 2, 2]
    assert auto_workers(100, cores=8) == 8 and auto_workers(12, cores=8) == 6
    assert worker_groups(1, AUTO) == [range(0, 1)]
    # the root's own share is smaller by what it does besides (channel, ledger, recordings)
    assert worker_groups(10, 2, root_overhead=0.2) == [range(0, 4), range(4, 10)]
    assert worker_groups(100, 2, root_overhead=0.2) == [range(0, 40), range(40, 100)]
    assert worker_groups(10, 3, root_overhead=0.2) == [range(0, 2), range(2, 6), range(6, 10)]
    assert worker_groups(20, 8, root_overhead=0.2)[0] == range(0, 1)  # never an empty root share
    assert worker_groups(5, 1, root_overhead=0.2) == [range(0, 5)]
    with pytest.raises(ScenarioError, match="--workers must be >= 1"):
        parse_workers("0")
    with pytest.raises(ScenarioError, match="'auto', got 'many'"):
        parse_workers("many")


def _row(tick: int, truth: list[object]) -> Row:
    return Row(tick, tick * 4_000_000, 0.0, 0.0, truth, [(0.0,) * 4] * len(truth), [0] * len(truth))


def test_the_ledger_takes_each_tick_of_each_vehicle_once_and_in_order() -> None:
    """The root's own vehicle 0 is known at every tick; vehicle 1's host reports at phase ticks (every 3rd
    here) with the ticks since its last report. A tick is complete only with both, in order; a host that
    reports a tick twice or one the run never stepped, or misses one, fails the run naming the vehicle."""
    truth = p.TruthReport((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 47.0, 8.0, 489.0, False, False)
    ledger = Ledger(2)
    for tick in range(3):
        ledger.open(_row(tick, ["own", None]))
        assert list(ledger.complete()) == []
    ledger.reported(1, 2, [p.TickReport(truth, (0.5,) * 4, k) for k in range(3)])
    done = list(ledger.complete())
    assert [r.tick for r in done] == [0, 1, 2] and [r.status[1] for r in done] == [0, 1, 2]
    assert all(r.truth == ["own", truth] and r.motors[1] == (0.5,) * 4 for r in done)
    ledger.check_through(2)
    ledger.open(_row(3, ["own", None]))
    with pytest.raises(SimulationError, match="vehicle 1 reported tick 2, which this run did not step"):
        ledger.reported(1, 3, [p.TickReport(truth, (0.5,) * 4, 0)] * 2)
    ledger.reported(1, 3, [p.TickReport(truth, (0.5,) * 4, 0)])
    ledger.open(_row(4, ["own", None]))
    ledger.open(_row(5, ["own", None]))
    ledger.reported(1, 5, [p.TickReport(truth, (0.5,) * 4, 0)])  # tick 5 only: tick 4 is missing
    with pytest.raises(SimulationError, match="vehicle 1 reported tick 5, which it had already reported"):
        ledger.reported(1, 5, [p.TickReport(truth, (0.5,) * 4, 0)])
    assert [r.tick for r in ledger.complete()] == [3]
    with pytest.raises(SimulationError, match=r"no ground truth for vehicles \[1\] at tick 4"):
        ledger.check_through(5)


def _fly(out: Path, workers: int, *scenario: str) -> dict[str, list[dict[str, object]]]:
    """4 vehicles flying the pymavlink mission with seed 5 (``scenario``: a scenario file and ``--set``s)."""
    vehicles = ["--vehicles", "4", "--mission", str(MISSIONS / "pymavlink_takeoff.py")] if not scenario else []
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "harness.cli",
            "run",
            *scenario,
            "--no-progress",
            *vehicles,
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


def _same_flights(one: dict[str, list[dict[str, object]]], other: dict[str, list[dict[str, object]]]) -> None:
    """Every recorded sample of every vehicle (time, pose, velocity, position, motors, flags) is identical."""
    for i in range(4):
        a, b = one[f"/vehicle/{i}/state"], other[f"/vehicle/{i}/state"]
        assert len(a) == len(b) > 500
        assert max(-float(s["pos_ned_m"][2]) for s in a) > 2.0  # it flew  # type: ignore[index]
        worst = max(math.dist(x["pos_ned_m"], y["pos_ned_m"]) for x, y in zip(a, b, strict=True))  # type: ignore[arg-type]
        assert a == b, f"vehicle {i}: the recordings differ (positions by up to {worst * 1000:.3f} mm)"


@pytest.mark.sim
def test_same_ground_truth_with_one_or_three_workers(tmp_path: Path) -> None:
    """pymavlink missions (byte-reproducible, docs/simclock.md) on 4 vehicles, seed 5: every recorded sample
    of every vehicle is identical whether `harness run` steps every vehicle or 3 processes each step the
    physics and autopilots of their share (vehicles 0-1 here, 2 and 3 in autopilot hosts)."""
    one = _fly(tmp_path / "one", 1)
    three = _fly(tmp_path / "three", 3)
    assert sorted((tmp_path / "three").glob("autopilot*.stderr")) == [
        tmp_path / "three" / "autopilot-1.stderr",
        tmp_path / "three" / "autopilot.stderr",
    ]
    _same_flights(one, three)


@pytest.mark.sim
def test_wind_and_turbulence_are_the_same_in_every_worker(tmp_path: Path) -> None:
    """Steady wind, moderate turbulence, sensor noise: each vehicle's random streams (its share of the run's
    seed) and its wind must be the same in a worker as in the root. A worker that stepped a vehicle twice,
    not at all, or with another vehicle's seed would fly another track."""
    scenario = tmp_path / "gusty.toml"
    scenario.write_text(
        f"""
[wind]
north_m_s = 2.0
east_m_s = -1.0
turbulence = "moderate"

[vehicles]
count = 4
mission = "{MISSIONS / "pymavlink_takeoff.py"}"
"""
    )
    one = _fly(tmp_path / "one", 1, str(scenario))
    three = _fly(tmp_path / "three", 3, str(scenario))
    _same_flights(one, three)


@pytest.mark.sim
def test_losing_a_worker_ends_the_run_naming_it(tmp_path: Path) -> None:
    """kill -9 of the autopilot host that flies (and simulates) vehicle 2: the run fails at once with one
    line that names the process, in `harness run`'s stderr and in summary.json; nothing is left running."""
    out = tmp_path / "run"
    proc = harness(
        "run",
        "--no-progress",
        "--vehicles",
        "3",
        "--workers",
        "3",
        "--mission",
        str(MISSIONS / "hover.py"),
        "--out",
        str(out),
        "--",
        "300",
    )
    try:
        wait_for_sim_time(proc, out, 5.0, 180)
        worker = [pid for pid in pids_with_run_dir(out) if b"autopilot-1.json" in _cmdline(pid)]
        assert len(worker) == 1, "one process is autopilot-1"
        os.kill(worker[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "autopilot-1" in lines[0], err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "autopilot-1" in summary["message"], summary["message"]
    gone = time.monotonic() + 10.0
    while pids_with_run_dir(out) and time.monotonic() < gone:
        time.sleep(0.1)
    assert not pids_with_run_dir(out), "every process of the run is gone"


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""
