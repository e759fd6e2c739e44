"""What a run reports: its status and the per-vehicle summary written to ``summary.json``."""

from __future__ import annotations

import enum
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any


class RunStatus(enum.StrEnum):
    """A run's outcome: ``summary.json``'s ``status`` (ok, failed, interrupted), and in a sweep's results.csv
    also what the sweep saw of a run that wrote no summary (timeout, lost)."""

    OK = "ok"
    FAILED = "failed"
    INTERRUPTED = "interrupted"
    TIMEOUT = "timeout"
    LOST = "lost"
    """``harness run`` ended without writing a summary (killed, or a crash before it started)."""


@dataclass
class VehicleSummary:
    id: int
    mission: str | None
    mission_exit_code: int | None = None
    max_altitude_m: float = 0.0
    final_position_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    landed: bool = True
    armed: bool = False
    crashed: bool = False


@dataclass
class RunResult:
    status: RunStatus
    sim_time_s: float
    wall_time_s: float
    vehicles: list[VehicleSummary]
    faults: list[dict[str, Any]]
    message: str = ""

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else 0.0

    @property
    def exit_code(self) -> int:
        return 0 if self.status == RunStatus.OK else (130 if self.status == RunStatus.INTERRUPTED else 1)

    def to_json(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "message": self.message,
            "sim_time_s": self.sim_time_s,
            "wall_time_s": self.wall_time_s,
            "real_time_factor": self.real_time_factor,
            "vehicles": [v.__dict__ | {"final_position_ned_m": list(v.final_position_ned_m)} for v in self.vehicles],
            "faults": self.faults,
        }


def write_summary(out: Path, result: RunResult, extra: dict[str, Any]) -> None:
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(result.to_json() | extra, indent=2))
    os.replace(tmp, out / "summary.json")
