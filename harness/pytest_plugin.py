"""pytest plugin of uav-harness (entry point ``pytest11``): fly missions inside tests, assert on the recording.

    def test_my_mission_lands_where_it_took_off(harness_run):
        run = harness_run(mission="missions/my_mission.py", vehicles=2, duration_s=300)
        assert run.ok, run.message
        assert run.vehicle(0).max_altitude_m > 9.5
        assert run.vehicle(1).distance_from_start_m() < 1.0
        n, e, d = run.vehicle(0).position_at(20.0)

Every run gets its own directory under pytest's ``tmp_path`` and its own ports, so the fixture is safe
under pytest-xdist. Tests that fly are marked ``sim`` (``pytest -m "not sim"`` skips them).

A sweep (``harness sweep`` on a local Dask cluster) across seeds and settings, asserting on the table:

    def test_hover_holds_in_wind(harness_sweep):
        sweep = harness_sweep("scenarios/wind_sweep.toml", seeds="0-3", sets={"wind.north_m_s": [0, 8]})
        assert sweep.ok, sweep.message
        assert all(d < 1.0 for d in sweep.column("v0.max_drift_m"))
        calm = sweep.where({"wind.north_m_s": 0})
"""

from __future__ import annotations

import bisect
import json
import math
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import pytest

from harness.autopilot.mathutil import quat_to_euler
from harness.record.status import read_summary
from harness.record.world import read_topics
from harness.run.result import RunStatus
from harness.sweep.results import read_results


@dataclass
class VehicleRecord:
    """One vehicle of a finished run: its summary line and its ground-truth track."""

    summary: dict[str, Any]
    track: list[dict[str, Any]]
    """``/vehicle/<i>/state`` messages of world.mcap: t_s, pos_ned_m, vel_ned_m_s, on_ground, crashed."""
    poses: list[dict[str, Any]] = field(default_factory=list)
    """``/vehicle/<i>/pose`` messages (foxglove.PoseInFrame, NED), one per state message."""

    def attitudes_deg(self) -> list[tuple[float, float, float, float]]:
        """(t_s, roll, pitch, yaw) in degrees, yaw in (-180, 180], from the true orientation."""
        out = []
        for state, pose in zip(self.track, self.poses, strict=False):
            q = pose["pose"]["orientation"]
            roll, pitch, yaw = quat_to_euler((q["w"], q["x"], q["y"], q["z"]))
            out.append((state["t_s"], math.degrees(roll), math.degrees(pitch), math.degrees(yaw)))
        return out

    @property
    def max_altitude_m(self) -> float:
        return float(self.summary["max_altitude_m"])

    @property
    def final_position_ned_m(self) -> tuple[float, float, float]:
        n, e, d = self.summary["final_position_ned_m"]
        return (n, e, d)

    @property
    def landed(self) -> bool:
        return bool(self.summary["landed"])

    @property
    def crashed(self) -> bool:
        return bool(self.summary.get("crashed", False))

    @property
    def mission_exit_code(self) -> int | None:
        code = self.summary.get("mission_exit_code")
        return None if code is None else int(code)

    def position_at(self, t_s: float) -> tuple[float, float, float]:
        """True position (NED, m) at sim time ``t_s`` (the recorded sample at or just before it)."""
        times = [m["t_s"] for m in self.track]
        i = max(0, bisect.bisect_right(times, t_s) - 1)
        n, e, d = self.track[i]["pos_ned_m"]
        return (n, e, d)

    def altitude_at(self, t_s: float) -> float:
        return -self.position_at(t_s)[2]

    def distance_from_start_m(self) -> float:
        """Horizontal distance between where the vehicle started and where it ended."""
        (n0, e0, _), (n1, e1, _) = self.track[0]["pos_ned_m"], self.track[-1]["pos_ned_m"]
        return math.hypot(n1 - n0, e1 - e0)


@dataclass
class RunRecord:
    """A finished ``harness run``: exit code, summary and recording."""

    out: Path
    returncode: int
    stdout: str
    stderr: str

    @cached_property
    def summary(self) -> dict[str, Any]:
        return read_summary(self.out)  # a killed run reads as status "killed"

    @cached_property
    def topics(self) -> dict[str, list[Any]]:
        return read_topics(self.out / "world.mcap")

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and self.summary.get("status") == RunStatus.OK

    @property
    def message(self) -> str:
        return f"{self.summary.get('status')}: {self.summary.get('message')}\n{self.stderr[-2000:]}"

    def vehicle(self, i: int) -> VehicleRecord:
        topics = self.topics
        return VehicleRecord(
            self.summary["vehicles"][i], topics.get(f"/vehicle/{i}/state", []), topics.get(f"/vehicle/{i}/pose", [])
        )

    def mission_output(self, i: int) -> str:
        return (self.out / f"mission-{i}.stdout").read_text()


def run_harness(
    out: Path,
    mission: str | Path | Sequence[str | Path],
    vehicles: int | None = None,
    duration_s: float | None = None,
    speed: float | None = None,
    seed: int = 0,
    args: Sequence[str] = (),
    extra: Sequence[str] = (),
    timeout_s: float = 600.0,
) -> RunRecord:
    """Run ``harness run`` in a subprocess (no state shared with the test process) and load the result.

    ``args`` go to the mission script, ``extra`` to ``harness run`` itself.
    """
    missions = [mission] if isinstance(mission, str | Path) else list(mission)
    cmd = [sys.executable, "-m", "harness.cli", "run", "--out", str(out), "--seed", str(seed)]
    for m in missions:
        cmd += ["--mission", str(m)]
    if vehicles is not None:
        cmd += ["--vehicles", str(vehicles)]
    if duration_s is not None:
        cmd += ["--duration", str(duration_s)]
    if speed is not None:
        cmd += ["--speed", str(speed)]
    cmd += list(extra)
    if args:
        cmd += ["--", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    return RunRecord(out, proc.returncode, proc.stdout, proc.stderr)


@pytest.fixture
def harness_run(tmp_path: Path) -> Callable[..., RunRecord]:
    """Returns ``fly(mission=..., vehicles=..., duration_s=..., speed=..., seed=..., args=...) -> RunRecord``."""
    counter = iter(range(1_000_000))

    def fly(**kwargs: Any) -> RunRecord:
        return run_harness(tmp_path / f"run-{next(counter)}", **kwargs)

    return fly


@dataclass
class SweepRecord:
    """A finished ``harness sweep``: exit code, output and its results.csv as typed rows."""

    out: Path
    returncode: int
    stdout: str
    stderr: str

    @cached_property
    def rows(self) -> list[dict[str, Any]]:
        path = self.out / "results.csv"
        return read_results(path) if path.is_file() else []

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and bool(self.rows) and all(r.get("status") == RunStatus.OK for r in self.rows)

    @property
    def message(self) -> str:
        bad = [
            f"{r['run']}: {r.get('status')}: {r.get('message')}" for r in self.rows if r.get("status") != RunStatus.OK
        ]
        return "\n".join([f"exit {self.returncode}", *bad, self.stderr[-2000:]])

    def column(self, name: str) -> list[Any]:
        """One column over every run, in the sweep's order."""
        return [r.get(name) for r in self.rows]

    def where(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """The rows whose columns equal ``params`` (``{"wind.north_m_s": 8, "seed": 0}``)."""
        return [r for r in self.rows if all(r.get(k) == v for k, v in params.items())]


def _toml_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(json.dumps(v) if isinstance(v, str) else _toml_text(v) for v in value) + "]"
    return str(value)


def run_sweep(
    out: Path,
    scenario: str | Path,
    seeds: str | None = None,
    sets: Mapping[str, Sequence[Any]] | None = None,
    extra: Sequence[str] = (),
    timeout_s: float = 1200.0,
) -> SweepRecord:
    """Run ``harness sweep`` in a subprocess; ``sets`` maps dotted paths to their values (``[0, 4, 8]``)."""
    cmd = [sys.executable, "-m", "harness.cli", "sweep", str(scenario), "--out", str(out)]
    if seeds is not None:
        cmd += ["--seeds", seeds]
    for path, values in (sets or {}).items():
        cmd += ["--set", f"{path}=" + ",".join(_toml_text(v) for v in values)]
    cmd += list(extra)
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    return SweepRecord(out, proc.returncode, proc.stdout, proc.stderr)


@pytest.fixture
def harness_sweep(tmp_path: Path) -> Callable[..., SweepRecord]:
    """Returns ``sweep(scenario, seeds=..., sets={...}, extra=[...]) -> SweepRecord`` (a directory per call)."""
    counter = iter(range(1_000_000))

    def sweep(scenario: str | Path, **kwargs: Any) -> SweepRecord:
        return run_sweep(tmp_path / f"sweep-{next(counter)}", scenario, **kwargs)

    return sweep


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "sim: a test that flies a real simulation (physics, autopilot, missions)")
    config.addinivalue_line("markers", "soak: a long-running soak test; CI runs it at a small size")
