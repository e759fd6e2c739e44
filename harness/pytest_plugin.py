"""pytest plugin of uav-harness (entry point ``pytest11``): fly missions inside tests, assert on the recording.

    def test_my_mission_lands_where_it_took_off(harness_run):
        run = harness_run(mission="missions/my_mission.py", vehicles=2, duration_s=300)
        assert run.ok, run.message
        assert run.vehicle(0).max_altitude_m > 9.5
        assert run.vehicle(1).distance_from_start_m() < 1.0
        n, e, d = run.vehicle(0).position_at(20.0)

Every run gets its own directory under pytest's ``tmp_path`` and its own ports, so the fixture is safe
under pytest-xdist. Tests that fly are marked ``sim`` (``pytest -m "not sim"`` skips them).
"""

from __future__ import annotations

import bisect
import json
import math
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import pytest

from harness.autopilot.mathutil import quat_to_euler
from harness.record.world import read_topics


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
        return dict(json.loads((self.out / "summary.json").read_text()))

    @cached_property
    def topics(self) -> dict[str, list[Any]]:
        return read_topics(self.out / "world.mcap")

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and self.summary.get("status") == "ok"

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


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "sim: a test that flies a real simulation (physics, autopilot, missions)")
    config.addinivalue_line("markers", "soak: a long-running soak test; CI runs it at a small size")
